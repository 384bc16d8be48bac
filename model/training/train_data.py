"""The LightningDataModule of `python -m model.train`: the farm's scenes split by body, the
training pack, the training and validation datasets (model.samples.data) and their loaders."""

from __future__ import annotations

import sys
from pathlib import Path

import lightning as L
import numpy as np
import torch

from model.samples.data import EvaluationPairs, TrainingScenes
from model.samples.data_augment import preset_training_lights
from model.samples.data_crops import DEFAULT_PADDING, PackedScenes, pack_scenes
from model.samples.data_splits import find_scenes, held_out_light_names, split_by_body


class EpochShuffleSampler(torch.utils.data.Sampler):
    """Shuffles per epoch and yields epoch * N + i, so each item's augmentation seed is
    fixed by (seed, epoch, i) whatever the number of workers or a resume in between."""

    def __init__(self, n: int, seed: int):
        self.n, self.seed, self.epoch = n, seed, 0

    def set_epoch(self, epoch: int) -> None:  # Lightning calls this at every epoch start
        self.epoch = epoch

    def __len__(self) -> int:
        return self.n

    def __iter__(self):
        order = np.random.default_rng([self.seed, self.epoch]).permutation(self.n)
        return iter((self.epoch * self.n + order).tolist())


class EpochIndexed(torch.utils.data.Dataset):
    """Maps the sampler's epoch * N + i back to item i with augmentation epoch `epoch`."""

    def __init__(self, dataset: TrainingScenes):
        self.dataset = dataset

    def __len__(self) -> int:
        return len(self.dataset)

    def __getitem__(self, k: int) -> dict:
        n = len(self.dataset)
        return self.dataset.item(k % n, epoch=k // n)


def first_scenes(folders, limit: int | None = None) -> list[Path]:
    """Finished scenes of `folders` in order (each folder's by index), the first `limit` of them."""
    scenes = [path for folder in folders for path in find_scenes(folder)]
    if limit is None:
        return scenes
    if not 1 <= limit <= len(scenes):
        raise ValueError(f"--max-scenes {limit}: the data has {len(scenes)} finished scenes")
    return scenes[:limit]


class SceneDataModule(L.LightningDataModule):
    """Training samples (TrainingScenes, `augment` its keyword options) and validation pairs
    (EvaluationPairs of the bodies held out by `val_fraction`) of `folders`' scenes.

    `presets`: extra training lights from the bundled HDR presets too (else scene lights only);
    `pack`: a .npz of the cropped training scenes, made when missing or stale."""

    def __init__(self, folders, *, size: int, order: int, batch: int, seed: int = 0, max_scenes: int | None = None,
                 val_fraction: float = 0.1, padding: int = DEFAULT_PADDING, workers: int = 0, cache_scenes: int = 64,
                 pack: Path | None = None, presets: bool = True, augment: dict | None = None):
        super().__init__()
        self.size, self.order, self.batch, self.seed, self.padding = size, order, batch, seed, padding
        self.workers, self.cache_scenes, self.presets, self.augment = workers, cache_scenes, presets, augment or {}
        self.pack = None if pack is None else Path(pack)
        self.held_out = held_out_light_names()
        self.train_paths, self.val_paths = split_by_body(first_scenes(folders, max_scenes), val_fraction, seed=seed)
        self.train_set: TrainingScenes | None = None
        self.val_set: EvaluationPairs | None = None
        self._pack_checked = False

    def prepare_data(self) -> None:
        # model.train prepares before the Trainer does (has_validation): check the pack once
        if self.pack is None or self._pack_checked:
            return
        self._pack_checked = True
        try:
            PackedScenes(self.pack, self.train_paths, self.size, self.order, self.padding)
        except (OSError, ValueError, KeyError):  # missing, stale or unreadable: make it again
            pack_scenes(self.train_paths, self.pack, self.size, self.order, self.padding, self.held_out)

    def setup(self, stage: str | None = None) -> None:
        if self.train_set is not None:  # set up already (see prepare_data)
            return
        extra = preset_training_lights(self.order) if self.presets else []
        self.train_set = TrainingScenes(self.train_paths, self.size, self.order, padding=self.padding,
                                        extra_lights=extra, pack=self.pack, seed=self.seed, held_out=self.held_out,
                                        cache_size=self.cache_scenes, **self.augment)
        if self.val_paths:
            try:
                self.val_set = EvaluationPairs(self.val_paths, self.size, self.order, padding=self.padding,
                                               held_out=self.held_out,
                                               body_prior=bool(self.augment.get("body_prior")))
            except ValueError as exc:  # validation scenes without two path-traced lights
                print(f"model.train: no validation ({exc})", file=sys.stderr)

    @property
    def has_validation(self) -> bool:
        return self.val_set is not None

    def _loader_options(self) -> dict:
        return dict(num_workers=self.workers, persistent_workers=self.workers > 0)

    def train_dataloader(self):
        return torch.utils.data.DataLoader(EpochIndexed(self.train_set), batch_size=self.batch,
                                           sampler=EpochShuffleSampler(len(self.train_set), self.seed),
                                           drop_last=len(self.train_set) >= self.batch, **self._loader_options())

    def val_dataloader(self):
        if self.val_set is None:
            return []
        return torch.utils.data.DataLoader(self.val_set, batch_size=self.batch, shuffle=False,
                                           **self._loader_options())
