"""Relighting network, losses, data loading, training and evaluation (torch).

RelightNet is imported on first use, so that the torch-free parts
(model.scoring.metrics, model.evaluate_photos) load without torch.
"""

__all__ = ["RelightNet"]


def __getattr__(name):
    if name == "RelightNet":
        from model.networks.network import RelightNet

        return RelightNet
    raise AttributeError(f"module 'model' has no attribute {name!r}")
