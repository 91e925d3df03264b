"""BVH parse + forward kinematics throughput on one core (frames/s), plus NTU and H36M readers.

Usage: python bench/ingest.py      (prints one JSON line per figure)
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")  # one core, as the target states

import zipfile  # noqa: E402

from _util import emit, median_time  # noqa: E402
from conftest import archive_path, dataset_cfg  # noqa: E402

from motionsynth.data.archive import Archive  # noqa: E402
from motionsynth.data.bvh import parse_bvh  # noqa: E402
from motionsynth.data.ingest import build_reader  # noqa: E402
from motionsynth.data.ntu import parse_skeleton  # noqa: E402


def bvh_throughput(archive: str, members: list[str], end_sites: bool) -> tuple[float, int]:
    with zipfile.ZipFile(archive_path(archive)) as z:
        blobs = [z.read(m) for m in members]
    frames = sum(parse_bvh(b).num_frames for b in blobs)

    def run():
        for b in blobs:
            parse_bvh(b).positions(end_sites=end_sites)

    return frames / median_time(run, repeats=7), frames


def main() -> None:
    fps, n = bvh_throughput("cmu_aclstm", ["martial/04.bvh"], end_sites=True)
    emit("ingest_bvh_cmu", fps, "frames/s", 50000, file="martial/04.bvh", frames=n, joints=57,
         reference={"acLSTM reader": 261, "pybvh 0.9": 34000})
    with zipfile.ZipFile(archive_path("cmu_aclstm")) as z:
        allcmu = sorted(m for m in z.namelist() if m.count("/") == 1 and m.endswith(".bvh"))
    fps, n = bvh_throughput("cmu_aclstm", allcmu, end_sites=True)
    emit("ingest_bvh_cmu_all", fps, "frames/s", 50000, files=len(allcmu), frames=n)
    with zipfile.ZipFile(archive_path("bandai1")) as z:
        b1 = sorted(m for m in z.namelist() if m.endswith(".bvh"))[:40]
    fps, n = bvh_throughput("bandai1", b1, end_sites=False)
    emit("ingest_bvh_bandai", fps, "frames/s", None, files=len(b1), frames=n, joints=22)

    with zipfile.ZipFile(archive_path("ntu_samples")) as z:
        texts = [(z.read(m).decode(), m) for m in z.namelist()]
    frames = sum(parse_skeleton(t, m)["positions"].shape[0] for t, m in texts)
    dt = median_time(lambda: [parse_skeleton(t, m) for t, m in texts])
    emit("ingest_ntu", frames / dt, "frames/s", None, files=len(texts), frames=frames)

    cfg = dataset_cfg("h36m")
    reader = build_reader(cfg["reader"])
    with Archive(archive_path("h36m")) as ar:
        items, _ = reader.list_items(ar)
        items = items[:10]
        frames = sum(reader.read(ar, it)[0].num_frames for it in items)
        dt = median_time(lambda: [reader.read(ar, it) for it in items], repeats=3, warmup=1)
    emit("ingest_h36m_with_4_projections", frames / dt, "frames/s", None, files=len(items), frames=frames)


if __name__ == "__main__":
    main()
