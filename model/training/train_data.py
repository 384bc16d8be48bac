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
from model.samples.data_splits import find_scenes, held_out_light_names, split_by_body, split_by_key
from model.samples.training_pack import PackScenes


class EpochShuffleSampler(torch.utils.data.Sampler):
    """Shuffles per epoch and yields epoch * N + i, so each item's augmentation seed is
    fixed by (seed, epoch, i) whatever the number of workers or a resume in between.

    Each pass is the next epoch (Lightning makes one pass per epoch). resume_at(epoch, skip): the
    passes start at `epoch`, the first from its skip-th item on. A resumed Lightning run restarts the
    epoch's loader from its start, draws the first batch before it sets the epoch, and counts an epoch
    stopped by max_steps as finished; so the position comes from the steps done
    (SceneDataModule.train_dataloader), and a run resumed after k steps sees the batches of one never
    stopped."""

    def __init__(self, n: int, seed: int):
        self.n, self.seed, self.epoch, self.skip = n, seed, 0, 0

    def set_epoch(self, epoch: int) -> None:
        """Lightning's epoch count, not used: it differs from the passes made after a resume."""

    def resume_at(self, epoch: int, skip: int) -> None:
        self.epoch, self.skip = epoch, skip

    def __len__(self) -> int:
        return self.n

    def __iter__(self):
        epoch, skip = self.epoch, self.skip
        self.epoch, self.skip = epoch + 1, 0
        order = np.random.default_rng([self.seed, epoch]).permutation(self.n)
        return iter((epoch * self.n + order[skip:]).tolist())


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
    `pack`: a .npz of the cropped training scenes, made when missing or stale; `training_pack`: a
    model.samples.training_pack.TrainingPack to train from instead of `folders` (its scenes split
    by the body keys it recorded; no scene file is read)."""

    def __init__(self, folders, *, size: int, order: int, batch: int, seed: int = 0, max_scenes: int | None = None,
                 val_fraction: float = 0.1, padding: int = DEFAULT_PADDING, workers: int = 0, cache_scenes: int = 64,
                 pack: Path | None = None, presets: bool = True, augment: dict | None = None, training_pack=None):
        super().__init__()
        self.size, self.order, self.batch, self.seed, self.padding = size, order, batch, seed, padding
        self.workers, self.cache_scenes, self.presets, self.augment = workers, cache_scenes, presets, augment or {}
        self.pack = None if pack is None else Path(pack)
        self.held_out = held_out_light_names()
        self.training_pack = training_pack
        if training_pack is not None:
            if training_pack.manifest["held_out"] != sorted(self.held_out):
                raise ValueError(f"{training_pack.path}: packed when the held-out maps were "
                                 f"{', '.join(training_pack.manifest['held_out'])}; pack the scenes again")
            if (training_pack.size, training_pack.order) != (size, order):
                raise ValueError(f"{training_pack.path}: packed at {training_pack.size} px, order "
                                 f"{training_pack.order}; this run trains at {size} px, order {order}")
            chosen = list(range(len(training_pack.scenes)))[:max_scenes]
            self.train_paths, self.val_paths = split_by_key(
                chosen, [training_pack.body_keys[i] for i in chosen], val_fraction, seed=seed)
        else:
            self.train_paths, self.val_paths = split_by_body(first_scenes(folders, max_scenes), val_fraction,
                                                             seed=seed)
        self.train_set: TrainingScenes | None = None
        self.val_set: EvaluationPairs | None = None
        self._pack_checked = False

    def prepare_data(self) -> None:
        # model.train prepares before the Trainer does (has_validation): check the pack once
        if self.pack is None or self._pack_checked or self.training_pack is not None:
            return
        self._pack_checked = True
        try:
            PackedScenes(self.pack, self.train_paths, self.size, self.order, self.padding)
        except (OSError, ValueError, KeyError):  # missing, stale or unreadable: make it again
            pack_scenes(self.train_paths, self.pack, self.size, self.order, self.padding, self.held_out)

    def preset_lights(self) -> list[tuple[str, np.ndarray]]:
        """The bundled HDR presets' SH as extra training lights: the pack's own when it carries
        them (a compact pack: no EXR read), else projected from the maps; none with presets off."""
        if not self.presets:
            return []
        if self.training_pack is not None and self.training_pack.presets is not None:
            return self.training_pack.presets
        return preset_training_lights(self.order)

    def setup(self, stage: str | None = None) -> None:
        if self.train_set is not None:  # set up already (see prepare_data)
            return
        extra = self.preset_lights()
        if self.training_pack is not None:
            self._setup_from_pack(extra)
            return
        self.train_set = TrainingScenes(self.train_paths, self.size, self.order, padding=self.padding,
                                        extra_lights=extra, pack=self.pack, seed=self.seed, held_out=self.held_out,
                                        cache_size=self.cache_scenes, **self.augment)
        if self.val_paths:
            try:
                self.val_set = EvaluationPairs(self.val_paths, self.size, self.order, padding=self.padding,
                                               held_out=self.held_out,
                                               body_prior=bool(self.augment.get("body_prior")),
                                               depth=bool(self.augment.get("depth")))
            except ValueError as exc:  # validation scenes without two path-traced lights
                print(f"model.train: no validation ({exc})", file=sys.stderr)

    def _setup_from_pack(self, extra) -> None:
        pack = self.training_pack
        self.train_set = TrainingScenes(None, self.size, self.order, extra_lights=extra, seed=self.seed,
                                        held_out=self.held_out, scenes=PackScenes(
                                            [pack.scenes[i] for i in self.train_paths],
                                            [pack.names[i] for i in self.train_paths]), **self.augment)
        if self.val_paths:
            try:
                self.val_set = EvaluationPairs.from_scenes([pack.scenes[i] for i in self.val_paths], self.size,
                                                           self.order, body_prior=bool(self.augment.get("body_prior")),
                                                           depth=bool(self.augment.get("depth")))
            except ValueError as exc:
                print(f"model.train: no validation ({exc})", file=sys.stderr)

    @property
    def has_validation(self) -> bool:
        return self.val_set is not None

    def _loader_options(self) -> dict:
        return dict(num_workers=self.workers, persistent_workers=self.workers > 0)

    def train_dataloader(self):
        sampler = EpochShuffleSampler(len(self.train_set), self.seed)
        drop_last = len(self.train_set) >= self.batch
        trainer = self.trainer  # None outside a Trainer
        if trainer is not None and trainer.global_step > 0:  # resumed: continue where the batches stopped
            per_epoch = len(self.train_set) // self.batch if drop_last else -(-len(self.train_set) // self.batch)
            done = trainer.global_step * trainer.accumulate_grad_batches
            sampler.resume_at(done // per_epoch, (done % per_epoch) * self.batch)
        return torch.utils.data.DataLoader(EpochIndexed(self.train_set), batch_size=self.batch, sampler=sampler,
                                           drop_last=drop_last, **self._loader_options())

    def val_dataloader(self):
        if self.val_set is None:
            return []
        return torch.utils.data.DataLoader(self.val_set, batch_size=self.batch, shuffle=False,
                                           **self._loader_options())
