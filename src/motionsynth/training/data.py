"""Training data: prepared windows of one representation and split protocol, as :class:`Batch`es.

Frames stay memory-mapped; a batch is gathered from the window index table in
one vectorised step (:func:`motionsynth.data.clips.gather`) and normalised with
the protocol's train-split statistics. Shapes: ``pose`` ``[B, T, J, D]``,
``controls`` ``[B, T, 3]``, ``labels`` ``[B]``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Iterator, Mapping

import numpy as np
import pandas as pd
import torch

from ..data.clips import gather, windows
from ..data.normalise import Normaliser
from ..data.types import ConfigError, MissingDataError
from ..models.base import Batch, DataSpec


class WindowData:
    """The windows of ``family`` in ``split`` of one prepared representation."""

    def __init__(self, rep_dir: str | Path, split_dir: str | Path, protocol: str, family: str, split: str,
                 num_classes: int | None = None, controls: bool = True):
        rep_dir, split_dir = Path(rep_dir), Path(split_dir)
        ds = rep_dir.parent.name
        needs = (rep_dir / "representation.json", split_dir / f"{protocol}.csv", split_dir / f"{protocol}_stats.npz")
        for need in needs:
            if not need.exists():  # split@ds runs prepare@ds (and ingest@ds) first where they are not up to date
                raise MissingDataError(f"{need} is missing: `dvc repro split@{ds}` makes it "
                                       f"(with the rest of {ds}'s prepared data and splits)")
        self.rep = json.loads((rep_dir / "representation.json").read_text())
        skel = rep_dir / "skeleton.json"
        self.parents = tuple(int(p) for p in json.loads(skel.read_text())["parents"]) if skel.exists() else None
        wpath = rep_dir / f"windows_{family}.parquet"
        if not wpath.exists():
            raise ConfigError(f"{rep_dir}: no '{family}' windows; conf/dataset/{ds}.yaml: prepare.representations."
                              f"{rep_dir.name}.clips defines {[p.stem[8:] for p in rep_dir.glob('windows_*.parquet')]}")
        self.meta = pd.read_parquet(rep_dir / "meta.parquet")
        table = pd.read_csv(split_dir / f"{protocol}.csv").set_index("sequence_id")["split"]
        w = pd.read_parquet(wpath)
        self.windows = w[w["sequence_id"].map(table).to_numpy() == split].reset_index(drop=True)
        self.pose = np.load(rep_dir / "pose.npy", mmap_mode="r")
        self.root = np.load(rep_dir / "root.npy", mmap_mode="r")
        cpath = rep_dir / "controls.npy"
        self.controls = np.load(cpath, mmap_mode="r") if cpath.exists() and controls else None
        stats_path = split_dir / f"{protocol}_stats.npz"
        self.norm = Normaliser.load(stats_path)
        stats = np.load(stats_path)
        self.ctrl_mean = stats["controls_mean"] if "controls_mean" in stats.files else None
        self.ctrl_std = stats["controls_std"] if "controls_std" in stats.files else None
        self.offsets = self.meta["offset"].to_numpy()
        self.frames = self.meta["frames"].to_numpy()
        labels = self.meta["label"].to_numpy()
        self.classes = class_table(rep_dir, num_classes)
        self.num_classes = (len(self.classes) if self.classes is not None else
                            int(num_classes if num_classes is not None else max(labels.max() + 1, 0)))
        self.labels = labels
        self.every = int(self.windows["every"].iloc[0]) if len(self.windows) else 1
        self.length = int(self.windows["length"].iloc[0]) if len(self.windows) else 0

    def rewindow(self, length: int, stride: int | None = None) -> "WindowData":
        """Replace the windows with dense ``length``-frame windows over the same sequences
        (e.g. acLSTM's 100-frame training sequences); the split is kept."""
        seqs = np.unique(self.windows["seq"].to_numpy())
        w = windows(self.frames[seqs], length, stride or length, pad="none")
        w["seq"] = seqs[w["seq"].to_numpy()]
        w["every"] = 1
        w["sequence_id"] = self.meta["sequence_id"].to_numpy()[w["seq"].to_numpy()]
        self.windows, self.length, self.every = w.reset_index(drop=True), length, 1
        return self

    def __len__(self) -> int:
        return len(self.windows)

    @property
    def spec(self) -> DataSpec:
        return DataSpec(joints=int(self.pose.shape[1]), dims=int(self.pose.shape[2]), num_classes=self.num_classes,
                        controls=3 if self.controls is not None else 0, fps=float(self.rep["fps"]),
                        window=self.length, every=self.every, parents=self.parents)

    def batch(self, idx: np.ndarray) -> Batch:
        """Windows ``idx`` as a normalised :class:`Batch`."""
        w = self.windows.iloc[np.asarray(idx)]
        pose = gather(self.pose, self.offsets, self.frames, w)              # [B, T, J, D]
        root = gather(self.root, self.offsets, self.frames, w)              # [B, T, 3]
        pose = self.norm(pose, root).astype(np.float32)
        controls = None
        if self.controls is not None:
            c = gather(self.controls, self.offsets, self.frames, w, pad_value=0.0)   # padding stands still
            controls = torch.from_numpy(((c - self.ctrl_mean) / self.ctrl_std).astype(np.float32))
        labels = None
        if self.num_classes > 0:
            labels = torch.from_numpy(self.labels[w["seq"].to_numpy()].astype(np.int64))
        return Batch(torch.from_numpy(pose), controls, labels, self.every,
                     {"window": torch.from_numpy(np.asarray(idx, dtype=np.int64))})

    def iterate(self, batch_size: int, shuffle: bool, seed: int, epoch: int = 0,
                rank: int = 0, world: int = 1, drop_last: bool = False) -> Iterator[Batch]:
        """Batches over the windows; the order is a function of ``(seed, epoch)`` only, so a
        resumed run sees exactly the batches an uninterrupted one would. With ``world > 1``
        each rank takes every ``world``-th batch (DistributedSampler semantics)."""
        for b in self.batch_indices(batch_size, shuffle, seed, epoch, drop_last)[rank::world]:
            yield self.batch(b)

    def batch_indices(self, batch_size: int, shuffle: bool, seed: int, epoch: int = 0,
                      drop_last: bool = False) -> list[np.ndarray]:
        """The window indices of every batch of pass ``epoch``: the ``(seed, epoch)`` permutation (or
        window order) cut into ``batch_size`` pieces. The one definition of the batch order."""
        n = len(self)
        order = np.random.default_rng([seed, epoch]).permutation(n) if shuffle else np.arange(n)
        stop = n - n % batch_size if drop_last else n
        return [order[i:i + batch_size] for i in range(0, stop, batch_size)]


def class_table(rep_dir: str | Path, num_classes: int | None = None) -> list[dict] | None:
    """The prepared data's class table (``classes.json``, from ingest; ``None`` for data prepared
    before it existed). A configured ``training.num_classes`` must equal its length: else a
    :class:`ConfigError` names the field and the classes found."""
    path = Path(rep_dir) / "classes.json"
    if not path.exists():
        return None
    classes = json.loads(path.read_text())
    if num_classes is not None and int(num_classes) != len(classes):
        shown = ", ".join(f"{c['name']} (raw {c['raw']})" for c in classes[:12]) + (", ..." if len(classes) > 12 else "")
        raise ConfigError(f"conf/dataset/{Path(rep_dir).parent.name}.yaml: training.num_classes is {num_classes}, "
                          f"but the data holds {len(classes)} classes: {shown or 'none'}; "
                          f"set it to {len(classes)} or leave it out (null: taken from the data)")
    return classes


def open_split(processed: str | Path, splits: str | Path, dataset: str, training: Mapping, family: str,
               split: str) -> WindowData:
    """The windows of ``split`` for a dataset's training representation and protocol
    (``training: {representation, protocol}`` in ``conf/dataset/<ds>.yaml``)."""
    rep, proto = training["representation"], training["protocol"]
    return WindowData(Path(processed) / dataset / rep, Path(splits) / dataset / rep, proto, family, split,
                      training.get("num_classes"), bool(training.get("controls", True)))


def real_batch(dataset: str, family: str, n: int, tmp_dir: str | Path, max_items: int = 12,
               length: int | None = None) -> tuple[Batch, DataSpec]:
    """``n`` normalised train windows of a few real items of ``dataset`` (for tests and benchmarks).

    Ingests ``max_items`` items of the real archive (spread over classes) into
    ``tmp_dir``, prepares and splits them with the dataset's own config.
    """
    from omegaconf import OmegaConf

    from ..data.ingest import ingest
    from ..data.prepare import prepare
    from ..data.splits import split_dataset

    repo = Path(__file__).resolve().parents[3]
    cfg = OmegaConf.to_container(OmegaConf.load(repo / "conf" / "dataset" / f"{dataset}.yaml"), resolve=True)
    tmp = Path(tmp_dir)
    raw = repo / "data" / "raw" / cfg["archive"]
    if not raw.exists():  # not pulled: read it from the team's DVC store by its md5
        import yaml

        md5 = yaml.safe_load((repo / "data" / "raw" / f"{cfg['archive']}.dvc").read_text())["outs"][0]["md5"]
        raw = repo.parent / "shared" / "dvc-store" / "files" / "md5" / md5[:2] / md5[2:]
    if not (tmp / "splits").exists():
        ingest(cfg, raw, tmp / "interim", max_items=max_items, progress=False)
        prepare(tmp / "interim", tmp / "processed" / dataset, cfg["prepare"]["representations"])
        split_dataset(tmp / "processed" / dataset, tmp / "splits" / dataset, cfg["split"], seed=0)
    data = open_split(tmp / "processed", tmp / "splits", dataset, cfg["training"], family, "train")
    if length is not None:
        data.rewindow(length)
    if len(data) == 0:
        raise ValueError(f"{dataset}: no {family} train windows in {max_items} items")
    idx = np.unique(np.linspace(0, len(data) - 1, min(n, len(data))).round().astype(int))
    return data.batch(idx), data.spec
