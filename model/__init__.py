"""Relighting network, losses, data loading, training and evaluation (torch)."""

from model.network import RelightNet

__all__ = ["RelightNet"]
