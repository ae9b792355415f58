"""Training: joint or two-stage training of UNet++ and Swin (``train``), Swin fine-tuning on cached features
(``finetune``), and the prepare / train / export / evaluate pipeline of a GPU session (``pipeline``).

torch, and the simulator for data; never imported by the service, but for ``options`` (torch-free), whose
``AdaptOptions`` rules the API's adaptation options share.
"""
