"""The networks: UNet++ (frame enhancement) and a Swin transformer (attitude regression)."""
