"""`motionsynth generate`: both model families end to end on tiny models trained on a few real items,
the output files, schedule timing and pace, and the errors an animator gets (exit code 2)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO, archive_path, dataset_cfg

from motionsynth import cli
from motionsynth.data.bvh import parse_bvh
from motionsynth.data.types import Skeleton
from motionsynth.generate import (GenerateError, blend_seams, compose_config, frames_per_step, generate,
                                  parse_schedule, plan, seam_jumps)

pytestmark = pytest.mark.usefixtures("one_thread")  # see conftest.one_thread

SCHEDULE = "walk:4s,run:3s,walk-left:3s"
FAST = ["formats=[bvh,npz]"]  # GIF only where it is checked (it is the slowest part)


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> Path:
    """A project root as `dvc repro` leaves it, in miniature: a few real items of both datasets
    ingested, prepared and split, and smoke-size VAE-LSTM, GloGen and LocGen trained on them
    (1 epoch of 2 batches: the command only needs weights of the right shapes)."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from motionsynth.data.ingest import ingest
    from motionsynth.data.prepare import prepare
    from motionsynth.data.splits import split_dataset
    from motionsynth.training.run import run

    r = tmp_path_factory.mktemp("genroot")
    for ds, n in (("bandai2_locomotion", 8), ("bandai1", 16)):
        cfg = dataset_cfg(ds)
        ingest(cfg, archive_path(ds), r / "data/interim" / ds, max_items=n, progress=False)
        prepare(r / "data/interim" / ds, r / "data/processed" / ds, cfg["prepare"]["representations"])
        split_dataset(r / "data/processed" / ds, r / "data/splits" / ds, cfg["split"], seed=0)
    for ds, model in (("bandai2_locomotion", "vae_lstm"), ("bandai1", "glogen"), ("bandai1", "locgen")):
        with initialize_config_dir(str(REPO / "conf"), version_base="1.3"):
            c = compose("config", overrides=[f"paths.root={r}", f"dataset={ds}", f"model={model}", "profile=smoke",
                                             "tracking.enabled=false", "train.threads=1", "train.steps=2",
                                             "train.eval_every=2", "train.val_windows=4"])
        run(OmegaConf.to_container(c, resolve=True), progress=False)
    return r


def gen(root: Path, out: Path, *overrides: str):
    return generate([f"root={root}", f"out_dir={out}", *overrides])


def npz(path: Path) -> dict:
    with np.load(path) as d:
        return {k: d[k] for k in d.files}


# ------------------------------------------------------------------------------------------ VAE-LSTM
def test_vae_lstm_circle_preset_bvh_gif_npz(root, tmp_path):
    res = gen(root, tmp_path / "out", "model=vae_lstm", "path=circle", "seconds=10", "gif.fps=2")
    names = {f.name for f in res.files}
    assert names == {"vae_lstm_circle_10s.bvh", "vae_lstm_circle_10s.gif", "vae_lstm_circle_10s.npz"}
    assert all(f.stat().st_size > 0 for f in res.files)
    d = npz(tmp_path / "out/vae_lstm_circle_10s.npz")
    assert d["positions"].shape == (600, 21, 3) and float(d["fps"]) == 60.0      # 10 s x 60 fps
    assert d["controls"].shape == (600, 3) and str(d["path"]) == "circle"
    skel = Skeleton.load(root / "data/processed/bandai2_locomotion/pos3d/skeleton.json")
    assert d["joint_names"].tolist() == skel.names
    # the root follows the integrated path: a circle of radius 2.5 m (conf presets.circle), centre on the left (+X)
    hips = d["positions"][:, skel.index("Hips")]
    r = np.hypot(hips[:, 0] - 2.5, hips[:, 2])
    assert np.allclose(r[60:], 2.5, atol=0.05)
    assert np.allclose(d["root"][:, [0, 1]], hips[:, [0, 2]], atol=1e-5)
    # the BVH reads back: the skeleton's joints, the requested frames, the root where the NPZ has it
    bvh = parse_bvh((tmp_path / "out/vae_lstm_circle_10s.bvh").read_text())
    assert set(skel.names) <= set(bvh.names) and bvh.num_frames == 600
    assert bvh.frame_time == pytest.approx(1 / 60)
    back = bvh.positions(dtype=np.float64) / 100.0                                 # centimetres, as the sources
    assert np.allclose(back[:, bvh.names.index("Hips")], hips, atol=1e-4)
    from PIL import Image

    with Image.open(tmp_path / "out/vae_lstm_circle_10s.gif") as im:
        assert im.n_frames == 20                                                    # 10 s at gif.fps=2


def test_vae_lstm_csv_with_time_column_and_several_characters(root, tmp_path):
    t = np.arange(0, 11.0001, 0.1)
    csv = tmp_path / "walk.csv"
    csv.write_text("time,forward,sideways,turn\n" + "".join(f"{a:.1f},1.2,0,{0.3 * np.sin(a):.4f}\n" for a in t))
    res = gen(root, tmp_path / "out", "model=vae_lstm", f"path={csv}", "num_samples=2", "seed=3", *FAST)
    assert sorted(f.name for f in res.files) == ["vae_lstm_walk_11s_0.bvh", "vae_lstm_walk_11s_0.npz",
                                                   "vae_lstm_walk_11s_1.bvh", "vae_lstm_walk_11s_1.npz"]
    a, b = npz(tmp_path / "out/vae_lstm_walk_11s_0.npz"), npz(tmp_path / "out/vae_lstm_walk_11s_1.npz")
    assert a["positions"].shape == (661, 21, 3)                                     # 0..11 s resampled at 60 fps
    assert np.allclose(a["controls"][:, 0], 1.2) and np.allclose(a["controls"][120, 2], 0.3 * np.sin(2.0), atol=1e-3)
    assert not np.allclose(a["positions"], b["positions"])                         # two different characters
    assert np.allclose(a["root"], b["root"])                                         # on the same path
    # a per-frame CSV (no time column) cut to seconds=
    rows = tmp_path / "rows.csv"
    rows.write_text("forward;sideways;turn\n" + "1.0;0.0;0.1\n" * 700)               # ; as some spreadsheets write
    res = gen(root, tmp_path / "out2", "model=vae_lstm", f"path={rows}", "seconds=10.5", "formats=[npz]")
    assert npz(res.files[0])["positions"].shape[0] == 630


# ------------------------------------------------------------------------------------------ GloGen + LocGen
def test_glocal_schedule_switches_where_asked_and_pace_changes_length(root, tmp_path):
    out = {}
    for pace in (1.0, 2.0, 0.8):
        res = gen(root, tmp_path / f"p{pace}", "model=glocal", "schedule=walk:8s,run:6s,walk-left:6s", f"pace={pace}",
                  *(["gif.fps=2", "formats=[bvh,gif,npz]"] if pace == 1.0 else FAST))
        out[pace] = npz(next(f for f in res.files if f.suffix == ".npz"))
        bvh = parse_bvh(next(f for f in res.files if f.suffix == ".bvh").read_text())
        assert bvh.num_frames == len(out[pace]["positions"]) and bvh.frame_time == pytest.approx(1 / 30)
    one, fast, slow = out[1.0], out[2.0], out[0.8]
    names = dict(zip(one["class_labels"].tolist(), one["class_names"].tolist()))
    # pace 1: 20 s at 30 fps, walk until 8 s, run until 14 s, then walk-left
    assert one["positions"].shape == (600, 21, 3) and int(one["M"]) == 4
    assert one["switch_frames"].tolist() == [240, 420]
    seq = [names[c] for c in one["labels"]]
    assert seq[239] == "walk" and seq[240] == "run" and seq[419] == "run" and seq[420] == "walk-left"
    assert (tmp_path / "p1.0" / "glocal_walk-run-walk-left_pace1.gif").exists()
    # the same 120 sparse steps (the schedule in poses) at other paces: 3 frames per step (pace 5/3), 6 (5/6)
    assert np.array_equal(one["sparse"], fast["sparse"]) and np.array_equal(one["sparse"], slow["sparse"])
    assert (int(fast["M"]), len(fast["positions"]), fast["switch_frames"].tolist()) == (2, 360, [144, 252])
    assert (int(slow["M"]), len(slow["positions"]), slow["switch_frames"].tolist()) == (5, 720, [288, 504])
    assert float(fast["effective_pace"]) == pytest.approx(5 / 3)
    # keyframes are the same poses, only the in-betweens differ
    assert np.allclose(one["positions"][::5], fast["positions"][::3], atol=1e-5)
    assert np.allclose(one["positions"][::5], slow["positions"][::6], atol=1e-5)
    # GlocalNet has no trajectory: the character stays in place
    assert np.allclose(one["root"], 0) and np.abs(one["positions"][:, 0, [0, 2]]).max() < 1e-4
    assert str(one["seed_sequence"]).startswith("dataset-1_walk")                  # a real walk starts it


def test_glocal_open_last_entry_fills_seconds(root, tmp_path):
    res = gen(root, tmp_path, "model=glocal", "schedule=Walk:4s; walk_left", "seconds=12", "glocal.seed_motion=zeros",
              "formats=[npz]")
    d = npz(res.files[0])
    assert d["positions"].shape[0] == 360 and d["switch_frames"].tolist() == [120]
    assert str(d["schedule"]) == "walk:4s,walk-left:8s" and str(d["seed_sequence"]) == ""


def test_blend_seams_removes_a_jump_and_keeps_smooth_motion():
    x = np.cumsum(np.full((30, 2), 0.1), 0)
    x[15:] += 1.0                                                                   # a pop at pose 15
    assert seam_jumps(x, [15])[0] > 5 and seam_jumps(x, [10])[0] == pytest.approx(1.0)
    y = blend_seams(x, [15], 5)
    assert np.allclose(y[15] - y[14], y[14] - y[13]) and seam_jumps(y, [15])[0] < 1.5  # continues the velocity
    assert np.allclose(y[20:], x[20:]) and np.allclose(y[:15], x[:15])
    smooth = np.cumsum(np.full((30, 2), 0.1), 0)
    assert np.allclose(blend_seams(smooth, [5, 10, 15], 5), smooth)


def test_pace_frames_per_step():
    assert [frames_per_step(5, p) for p in (0.25, 0.5, 1, 1.5, 2, 2.5, 5)] == [20, 10, 5, 3, 3, 2, 1]


def test_parse_schedule():
    classes = {"walk": 0, "run": 1, "walk-left": 4}
    e = parse_schedule(" walk:4s ; RUN : 2.5 sec,walk_left", classes)
    assert [(x.name, x.label, x.seconds) for x in e] == [("walk", 0, 4.0), ("run", 1, 2.5), ("walk-left", 4, None)]


# ------------------------------------------------------------------------------------------ errors
def bad_csv(tmp_path: Path, name: str, text: str) -> str:
    p = tmp_path / name
    p.write_text(text)
    return str(p)


ERRORS = [
    (["model=glocal", "schedule=walk:4s,fly:6s"], r"unknown class 'fly'.*known classes: walk, run"),
    (["model=glocal", "schedule=walk:4s,rn:6s"], r"did you mean 'run'"),
    (["model=glocal", "schedule=walk:4x,run:6s"], r"'4x' is not a number of seconds"),
    (["model=glocal", "schedule=walk:4s,,run:6s"], r"entry 2 is empty"),
    (["model=glocal", "schedule=walk,run:6s"], r"only the last entry may omit"),
    (["model=glocal", "schedule=walk:4s,run"], r"has no duration.*seconds="),
    (["model=glocal", "schedule=walk:0.5s,run:10s"], r"first schedule entry 'walk' must last at least 0.833 s"),
    (["model=glocal", f"schedule={SCHEDULE}", "pace=2"], r"shorter than the minimum of 10 s.*lower the pace"),
    (["model=glocal", "pace=9"], r"pace=9 is outside 0.25..5"),
    (["model=glocal", "seconds=12"], r"seconds= only applies"),
    (["model=glocal", "num_samples=3"], r"deterministic"),
    (["model=glocal", "path=circle"], r"path= applies to model=vae_lstm"),
    (["model=vae_lstm", "schedule=walk:10s"], r"schedule= applies to model=glocal"),
    (["model=vae_lstm", "path=cirle"], r"unknown path preset 'cirle' \(did you mean 'circle'\?\); presets: straight"),
    (["model=vae_lstm", "seconds=-3"], r"seconds must be positive"),
    (["model=vae_lstm", "seconds=0"], r"seconds must be positive"),
    (["model=vae_lstm", "seconds=5"], r"5.00 s .*shorter than the minimum of 10 s"),
    (["model=vae_lstm", "seconds=ten"], r"seconds must be a number of seconds, got 'ten'"),
    (["model=vae_lstm", "path=missing.csv"], r"no such file"),
    (["model=vae_lstm", "CSV:nocol.csv:forward,turn\n1,0\n"], r"nocol.csv: missing column\(s\) sideways"),
    (["model=vae_lstm", "CSV:nan.csv:forward,sideways,turn\n1,0,0\n1,0,0\n1,,0\n"],
     r"nan.csv: row 4 \(counting the header as row 1\), column 'sideways' is empty"),
    (["model=vae_lstm", "CSV:text.csv:forward,sideways,turn\n1,0,0\nfast,0,0\n"],
     r"text.csv: row 3 .*column 'forward' is 'fast', not a finite number"),
    (["model=vae_lstm", "CSV:NaN.csv:forward,sideways,turn\n1,0,NaN\n"], r"row 2 .*column 'turn' is 'NaN'"),
    (["model=vae_lstm", "CSV:time.csv:time,forward,sideways,turn\n0,1,0,0\n2,1,0,0\n1,1,0,0\n"],
     r"time.csv: row 4, column 'time'.*times must increase"),
    (["model=vae_lstm", "CSV:short.csv:forward,sideways,turn\n" + "1,0,0\n" * 100], r"short.csv needs at least 600 rows"),
    (["model=vae_lstm", "vae_lstm.run=nope"], r"no trained vae_lstm model at .*nope/best.pt.*pipelines/train.py"),
    (["model=glocal", "models_dir=EMPTY", f"params_file={REPO / 'params.yaml'}"],
     r"no trained glogen model .*`dvc repro train@bandai1-glogen` produces it"),
    (["model=glocal", "processed_dir=EMPTY"], r"prepared data of bandai1 is missing.*dvc repro split@bandai1"),
    (["model=vae_lstm", "formats=[bvh,avi]"], r"unknown output format\(s\) \['avi'\]"),
    (["model=gan"], r"model='gan' is not a model family"),
    (["modle=glocal"], r"unknown option 'modle' \(did you mean 'model'\?\)"),
    (["model=vae_lstm", "glocal"], r"options are written key=value"),
]


@pytest.mark.parametrize("args, match", ERRORS, ids=[f"e{i}" for i in range(len(ERRORS))])
def test_bad_input_is_a_clear_error_before_any_work(root, tmp_path, args, match, capsys):
    args = list(args)
    for i, a in enumerate(args):
        if a.startswith("CSV:"):
            _, name, text = a.split(":", 2)
            args[i] = f"path={bad_csv(tmp_path, name, text)}"
        args[i] = args[i].replace("EMPTY", str(tmp_path / "empty"))
    out = tmp_path / "out"
    with pytest.raises(GenerateError, match=match):
        plan(compose_config([f"root={root}", f"out_dir={out}", *args]))
    assert cli.main(["generate", f"root={root}", f"out_dir={out}", *args]) == 2
    err = capsys.readouterr().err
    assert err.startswith("motionsynth generate: ") and "Traceback" not in err
    assert not out.exists()                                                          # nothing was written


def test_mp4_without_ffmpeg_is_a_clear_error(root, tmp_path, monkeypatch):
    monkeypatch.setenv("PATH", str(tmp_path))                                        # no ffmpeg on PATH
    monkeypatch.setenv("IMAGEIO_FFMPEG_EXE", str(tmp_path / "no-ffmpeg"))            # nor a usable bundled one
    with pytest.raises(GenerateError, match="mp4 output needs ffmpeg"):
        plan(compose_config([f"root={root}", "formats=[bvh,mp4]"]))


def test_mp4_output_is_h264_with_the_requested_frames(root, tmp_path):
    """MP4 through imageio-ffmpeg's bundled ffmpeg (no system ffmpeg): an ISO media file that
    decodes to 10 s x mp4.fps frames of a drawn (not blank) character."""
    from motionsynth.viz.animation import read_mp4

    res = gen(root, tmp_path, "model=vae_lstm", "path=straight", "seconds=10", "formats=[mp4]", "mp4.fps=3")
    mp4 = tmp_path / "vae_lstm_straight_10s.mp4"
    assert res.files == [mp4] and mp4.read_bytes()[4:8] == b"ftyp"
    meta, frames = read_mp4(mp4)
    assert meta["codec"] == "h264" and len(frames) == 30                             # every 20th of 600 frames
    assert all(f.min() < 100 < f.max() for f in frames[::10])                         # dark bones on a light figure


def test_console_command_exit_codes_and_help(root, tmp_path):
    env = {**os.environ, "PYTHONPATH": str(REPO / "src"), "OMP_NUM_THREADS": "1"}
    r = subprocess.run([sys.executable, "-m", "motionsynth.cli", "generate", f"root={root}", "model=glocal",
                        "schedule=walk:4s,swim:6s"], capture_output=True, text=True, env=env, cwd=tmp_path)
    assert r.returncode == 2 and "unknown class 'swim'" in r.stderr and "Traceback" not in r.stderr
    h = subprocess.run([sys.executable, "-m", "motionsynth.cli", "generate", "--help"], capture_output=True,
                       text=True, env=env, cwd=tmp_path)
    assert h.returncode == 0 and "Examples:" in h.stdout and "path=circle" in h.stdout and "schedule=" in h.stdout
    assert cli.main([]) == 2 and cli.main(["frobnicate"]) == 2 and cli.main(["--help"]) == 0
