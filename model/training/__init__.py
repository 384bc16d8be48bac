"""Training with Lightning: the LightningModule and LightningDataModule `python -m model.train` runs,
the losses, and weights saved as safetensors with a JSON config.
"""
