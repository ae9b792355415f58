"""The networks: UNet++ (frame enhancement), a Swin transformer (attitude regression), and their shapes
and construction (``build``). torch only."""
