"""``mrcomm record`` and ``evaluate --video``: frames are the env's own renders, streamed in constant memory."""

from __future__ import annotations

import importlib.util
import tracemalloc

import numpy as np
import pytest
from PIL import Image

import mrcomm_env
from mrcomm_baselines import make_policy
from mrcomm_env.experiments.cli import main
from mrcomm_env.experiments.record import TITLE_HEIGHT, GifWriter, record_episode

ENV = "MultiHop-v0"
PARAMS = {"grid_side": 3, "max_cycles": 6}


def gif_frames(path) -> list[np.ndarray]:
    with Image.open(path) as im:
        palette = im.getpalette()  # the global palette, read at the first frame
        frames = []
        for k in range(im.n_frames):
            im.seek(k)
            frames.append(np.asarray(im.convert("RGB")))
    return frames, palette


def test_the_frames_are_the_env_render_on_the_same_seed(tmp_path):
    out = tmp_path / "episode.gif"
    result = record_episode(ENV, ["location_based"], 5, out, params=PARAMS)
    frames, palette = gif_frames(out)
    assert result["frames"] == len(frames) == PARAMS["max_cycles"] + 1  # the reset and every step
    env = mrcomm_env.make(ENV, render_mode="rgb_array", **PARAMS)
    policy = make_policy(ENV, "location_based")
    obs, _ = env.reset(seed=5)
    policy.reset(env.local_views(), 5)
    reference = Image.new("P", (1, 1))
    reference.putpalette(palette)
    for k, frame in enumerate(frames):
        rendered = Image.fromarray(env.render()).quantize(palette=reference, dither=Image.Dither.NONE)
        assert np.array_equal(frame[TITLE_HEIGHT:], np.asarray(rendered.convert("RGB"))), f"frame {k}"
        if env.agents:
            obs, *_ = env.step(policy.act(obs, env.local_views()))


def test_policies_side_by_side_share_the_seed_and_double_the_width(tmp_path):
    one = record_episode(ENV, ["age_aware"], 2, tmp_path / "one.gif", params=PARAMS)
    two = record_episode(ENV, ["age_aware", "age_aware"], 2, tmp_path / "two.gif", params=PARAMS)
    (single, _), (double, _) = gif_frames(tmp_path / "one.gif"), gif_frames(tmp_path / "two.gif")
    assert double[0].shape[1] == 2 * single[0].shape[1]
    width = single[0].shape[1]
    for frame in double:  # the same policy on the same seed: both panels alike, step by step
        assert np.array_equal(frame[TITLE_HEIGHT:, :width], frame[TITLE_HEIGHT:, width:])
    assert two["metrics"]["age_aware"] == one["metrics"]["age_aware"]


def test_a_500_frame_recording_stays_in_constant_memory(tmp_path):
    """Frames are encoded as they come: writing 500 takes no more memory than writing 50 (a writer that kept
    them would hold 500 × 0.7 MB here)."""
    rng = np.random.default_rng(0)
    base = rng.integers(0, 255, size=(444, 540, 3), dtype=np.uint8)
    peaks = []
    for count in (50, 500):
        writer = GifWriter(tmp_path / f"{count}.gif", fps=10.0)
        tracemalloc.start()
        for k in range(count):
            frame = base.copy()
            frame[k % 400 : k % 400 + 40] = 255 - frame[k % 400 : k % 400 + 40]  # every frame differs
            writer.send(frame)
        writer.close_and_keep()
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
        with Image.open(tmp_path / f"{count}.gif") as im:
            assert im.n_frames == count
    assert peaks[1] < peaks[0] * 1.2 + 2**20, peaks


@pytest.mark.skipif(importlib.util.find_spec("imageio_ffmpeg") is not None, reason="the video extra is installed")
def test_mp4_without_the_video_extra_says_which_extra(tmp_path, capsys):
    with pytest.raises(ValueError, match=r"mrcomm-env\[video\]"):
        record_episode(ENV, ["random"], 0, tmp_path / "e.mp4", params=PARAMS)
    assert not list(tmp_path.iterdir()), "a refused recording leaves no file"
    assert main(["record", ENV, "--policy", "random", "--out", str(tmp_path / "e.mp4")]) != 0
    err = capsys.readouterr().err.strip()
    assert "video" in err and len(err.splitlines()) == 1 and "Traceback" not in err


def test_the_cli_records_and_evaluate_records_its_first_episode(tmp_path, capsys):
    out = tmp_path / "side.gif"
    args = ["--param", "grid_side=3", "--param", "max_cycles=4", "--seed", "1"]
    assert main(["record", ENV, "--policy", "location_based", "--policy", "age_aware", "--out", str(out), *args]) == 0
    assert "5 frames" in capsys.readouterr().out and out.stat().st_size > 0
    folder = tmp_path / "videos"
    assert main(["evaluate", ENV, "--policy", "age_aware", "--episodes", "2", "--video", str(folder), *args]) == 0
    assert len(gif_frames(folder / "MultiHop-v0-age_aware.gif")[0]) == 5
    assert main(["record", ENV, "--policy", "age_aware", "--out", str(tmp_path / "x.avi")]) != 0
    assert "'out'" in capsys.readouterr().err
