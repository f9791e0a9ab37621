"""``sqpmpc animate`` writes a playable animation of a run folder."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from sqpmpc.cli.main import main
from sqpmpc.io.animate import animate, frame_count, frame_size, load_run
from sqpmpc.io.files import write_run
from sqpmpc.problem.scenario_file import load_scenario
from sqpmpc.sim.simulation import simulate


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A short real decentralized run of paper-s2 (12 samples) written as ``sqpmpc run`` does."""
    out = tmp_path_factory.mktemp("run")
    record = simulate(load_scenario("paper-s2").with_changes(t_end=6.0), "decentralized")
    write_run(out, record, plots=False)
    return out


def _pixels(run_dir: Path) -> tuple[int, int]:
    """The frame's size: 640 px high, as wide as the run's extent asks, both even."""
    width, height = (round(100 * v) for v in frame_size(load_run(run_dir)))
    assert height == 640 and width % 2 == 0 and 400 <= width <= 1400
    return width, height


def test_frames_take_the_aspect_of_the_arena(run_dir: Path) -> None:
    run = load_run(run_dir)
    wide = load_run(run_dir)
    wide.states = run.states * np.array([3.0, 1.0, 1.0])  # three times as wide
    wide.references = run.references * np.array([3.0, 1.0])
    assert frame_size(wide)[0] > 1.5 * frame_size(run)[0]


def test_gif_has_one_frame_per_sample(run_dir: Path, capsys: pytest.CaptureFixture) -> None:
    out = run_dir / "a.gif"
    assert main(["animate", str(run_dir), "--out", str(out), "--fps", "5"]) == 0
    assert "13 frames" in capsys.readouterr().out
    with Image.open(out) as im:
        assert im.format == "GIF" and im.n_frames == 13 and im.size == _pixels(run_dir)
        assert im.info["duration"] == 200 and im.info["loop"] == 0
        first = np.asarray(im.convert("RGB"))
        im.seek(12)
        last = np.asarray(im.convert("RGB"))
    assert (first != last).any()  # the robots moved


def test_step_and_default_name(run_dir: Path, capsys: pytest.CaptureFixture) -> None:
    assert main(["animate", str(run_dir), "--step", "5"]) == 0
    with Image.open(run_dir / "animation.gif") as im:
        assert im.n_frames == 4  # samples 0, 5, 10 and the last, 12
    # progress: the first frame's line and the last one's, then the file
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("drawn 1/4 frames")
    assert lines[-2].startswith("drawn 4/4 frames") and lines[-2].endswith("writing the file")


def test_progress_is_called_after_every_frame(run_dir: Path, tmp_path: Path) -> None:
    calls: list[tuple[int, int]] = []
    run = load_run(run_dir)
    for step in (1, 4, 12, 13):
        calls.clear()
        _, frames = animate(run, tmp_path / f"s{step}.gif", step=step,
                            progress=lambda done, total: calls.append((done, total)))
        assert frames == frame_count(run, step)
        assert calls == [(i, frames) for i in range(1, frames + 1)]


def test_single_frame_png(run_dir: Path) -> None:
    out = run_dir / "f.png"
    assert main(["animate", str(run_dir), "--frame", "6", "--out", str(out)]) == 0
    with Image.open(out) as im:
        assert im.format == "PNG" and im.size == _pixels(run_dir)
        rgb = np.asarray(im.convert("RGB"))
    # robots of tab10 colours are drawn (not only white, grey and black)
    assert (np.ptp(rgb.astype(int), axis=-1) > 60).sum() > 500


@pytest.mark.skipif(importlib.util.find_spec("imageio_ffmpeg") is None,
                    reason="imageio-ffmpeg not installed (optional)")
def test_mp4(run_dir: Path) -> None:
    import imageio_ffmpeg

    out = run_dir / "a.mp4"
    assert main(["animate", str(run_dir), "--out", str(out)]) == 0
    frames, _ = imageio_ffmpeg.count_frames_and_secs(str(out))
    assert frames == 13


@pytest.mark.parametrize(("args", "needle"), [
    (["--out", "x.avi"], "--out"),
    (["--fps", "0"], "--fps"),
    (["--frame", "99"], "--frame"),
])
def test_bad_options_give_one_message(run_dir: Path, capsys: pytest.CaptureFixture,
                                      args: list[str], needle: str) -> None:
    if args[0] == "--out":
        args = ["--out", str(run_dir / args[1])]
    assert main(["animate", str(run_dir), *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and needle in err[0] and "Traceback" not in err[0]


def test_not_a_run_folder(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert main(["animate", str(tmp_path)]) == 2
    assert "no trajectory.npz" in capsys.readouterr().err
