"""Recording episodes: ``mrcomm record`` (several policies side by side on one seed) and ``evaluate --video``.

Each policy plays its own copy of the env from the same ``reset(seed)``; every step, each copy's
``render()`` becomes one panel, titled with the policy, the step, the env's headline metric and the bits sent
so far, and the panels are joined left to right into one frame. Frames are encoded as they come and never
kept: memory does not grow with the episode.

* GIF through Pillow (no extra dependency): the first frame fixes a 256-colour palette that every later frame
  is mapped onto, so each frame is written as soon as it is drawn (a GIF's global palette comes first).
* MP4 through ``imageio-ffmpeg`` (``pip install 'mrcomm-env[video]'``), fed frame by frame.

The file is written under a temporary name beside the target and renamed when the episode is done: an
interrupted recording leaves no half file.
"""

from __future__ import annotations

import gc
import os
from collections.abc import Callable, Generator, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from PIL import GifImagePlugin, Image, ImageDraw

from mrcomm_env.experiments.evaluation import make_any_policy
from mrcomm_env.experiments.runs import comparison_spec
from mrcomm_env.registry import canonical_id, make

VIDEO_EXTRA = "video"
SUFFIXES = (".gif", ".mp4")
TITLE_HEIGHT = 44  #: pixels of the caption above each panel
GC_EVERY = 16  #: frames between collections of what Pillow's GIF encoder leaves in reference cycles


def headline_metric(env_id: str, metrics: Mapping[str, str]) -> str:
    """The metric a panel shows: the one the learned-vs-scripted comparison ranks by, else the env's first."""
    try:
        name = comparison_spec(env_id)["metric"]
    except (ValueError, KeyError, ImportError):  # no comparison configured, or no "train" extra to read it
        name = ""
    return name if name in metrics else next(iter(metrics))


def record_episode(
    env_id: str,
    policies: Sequence[str],
    seed: int,
    out: str | Path,
    params: dict[str, Any] | None = None,
    policy_params: dict[str, Any] | None = None,
    max_steps: int | None = None,
    fps: float = 4.0,
    trust_pickle: bool = False,
) -> dict[str, Any]:
    """Record one episode of each policy in ``policies`` side by side into ``out`` (.gif or .mp4).
    ``trust_pickle``: learned models may come from runs written before the formats that load without running code.

    Returns ``{"frames", "path", "bytes", "metrics": {policy: final metrics}}``. Bad input (suffix, policy,
    arguments, the missing video extra) raises ``ValueError`` before any frame is drawn."""
    env_id = canonical_id(env_id)
    out = Path(out)
    if out.suffix.lower() not in SUFFIXES:
        raise ValueError(f"argument 'out' must end in {' or '.join(SUFFIXES)}, got {str(out)!r}")
    if not policies:
        raise ValueError("name at least one --policy")
    if max_steps is not None and max_steps < 1:
        raise ValueError(f"argument 'max_steps' must be an integer ≥ 1 or None, got {max_steps!r}")
    if not (isinstance(fps, (int, float)) and 0 < fps <= 100):
        raise ValueError(f"argument 'fps' must be a number in (0, 100], got {fps!r}")
    params = dict(params or {})
    agents = [make_any_policy(env_id, name, trust_pickle, **dict(policy_params or {})) for name in policies]
    envs = [make(env_id, render_mode="rgb_array", **{**getattr(p, "env_kwargs", {}), **params}) for p in agents]
    writer = _writer(out, fps)  # the video extra is checked before any episode runs
    frames = 0
    finals: dict[str, dict[str, float]] = {}
    try:
        metric = headline_metric(env_id, envs[0].METRICS)
        for frame in _frames(envs, agents, list(policies), seed, metric, max_steps):
            writer.send(frame)
            frames += 1
        finals = {name: env.metrics() for name, env in zip(policies, envs)}
        writer.close_and_keep()
    except BaseException:
        writer.discard()
        raise
    finally:
        for env in envs:
            env.close()
    return {"frames": frames, "path": str(out), "bytes": out.stat().st_size, "metrics": finals}


def _frames(envs, agents, names, seed: int, metric: str, max_steps: int | None) -> Iterator[np.ndarray]:
    observations = []
    for env, agent in zip(envs, agents):
        obs, _ = env.reset(seed=seed)
        agent.reset(env.local_views(), seed)
        observations.append(obs)
    step = 0
    while True:
        yield np.hstack([_panel(env, name, step, metric) for env, name in zip(envs, names)])
        if not any(env.agents for env in envs) or (max_steps is not None and step >= max_steps):
            return
        for k, (env, agent) in enumerate(zip(envs, agents)):
            if env.agents:  # a copy whose episode ended keeps showing its last frame
                observations[k], *_ = env.step(agent.act(observations[k], env.local_views()))
        step += 1


def _panel(env, name: str, step: int, metric: str) -> np.ndarray:
    """The env's own ``render()`` with a caption above it: policy, step, headline metric, bits so far."""
    image = env.render()
    value = env.metrics().get(metric, float("nan"))
    caption = Image.new("RGB", (image.shape[1], TITLE_HEIGHT), "white")
    draw = ImageDraw.Draw(caption)
    draw.text((6, 4), name, fill="black")
    shown = "not yet" if value != value else f"{value:.4g}"  # nan: a time to an event that has not happened
    draw.text((6, 22), f"step {step}   {metric} {shown}   bits {env.bits_sent():,.0f}", fill="black")
    return np.vstack([np.asarray(caption), image])


# --------------------------------------------------------------------------------------------- writers
class _Writer:
    """A streaming encoder into a temporary file that becomes ``out`` only when closed whole."""

    def __init__(self, out: Path):
        self.out = out
        self.tmp = out.with_name(f".{out.name}.tmp{out.suffix}")
        out.parent.mkdir(parents=True, exist_ok=True)

    def send(self, frame: np.ndarray) -> None:  # pragma: no cover - interface
        raise NotImplementedError

    def _finish(self) -> None:  # pragma: no cover - interface
        raise NotImplementedError

    def close_and_keep(self) -> None:
        self._finish()
        os.replace(self.tmp, self.out)

    def discard(self) -> None:
        try:
            self._finish()
        except Exception:  # noqa: BLE001 - the file is thrown away anyway
            pass
        self.tmp.unlink(missing_ok=True)


class GifWriter(_Writer):
    """GIF frames written one by one: header and global palette with the first frame, then each frame's data."""

    def __init__(self, out: Path, fps: float):
        super().__init__(out)
        self.fh = open(self.tmp, "wb")  # noqa: SIM115 - closed by _finish
        self.duration = max(int(round(1000.0 / fps)), 20)
        self.palette: Image.Image | None = None
        self.size: tuple[int, int] | None = None
        self.frames = 0

    def send(self, frame: np.ndarray) -> None:
        image = Image.fromarray(np.ascontiguousarray(frame[..., :3]), "RGB")
        if self.palette is None:
            self.palette = image.quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
            self.size = image.size
            for chunk in GifImagePlugin.getheader(self.palette, info={"duration": self.duration, "loop": 0})[0]:
                self.fh.write(chunk)
        elif image.size != self.size:
            raise ValueError(f"frame of size {image.size} in a recording of {self.size}")
        indexed = image.quantize(palette=self.palette, dither=Image.Dither.NONE)
        for chunk in GifImagePlugin.getdata(indexed, duration=self.duration, disposal=1):
            self.fh.write(chunk)
        self.frames += 1
        if self.frames % GC_EVERY == 0:
            # Pillow's getdata builds a class per call, whose reference cycle keeps the frame's encoded bytes
            # until a full collection: without this, memory grew by ~100 kB a frame
            gc.collect()

    def _finish(self) -> None:
        if not self.fh.closed:
            self.fh.write(b";")  # the GIF trailer
            self.fh.close()


class Mp4Writer(_Writer):
    def __init__(self, out: Path, fps: float, write_frames: Callable):
        super().__init__(out)
        self.fps = fps
        self.write_frames = write_frames
        self.gen: Generator[None, np.ndarray, None] | None = None

    def send(self, frame: np.ndarray) -> None:
        frame = np.ascontiguousarray(frame[..., :3])
        if self.gen is None:
            height, width = frame.shape[:2]
            gen = self.write_frames(
                str(self.tmp), (width, height), fps=self.fps, codec="libx264", macro_block_size=2, quality=7
            )
            gen.send(None)  # imageio-ffmpeg's generator starts ffmpeg on its first send
            self.gen = gen
        self.gen.send(frame)

    def _finish(self) -> None:
        if self.gen is not None:
            self.gen.close()
            self.gen = None


def _writer(out: Path, fps: float) -> _Writer:
    if out.suffix.lower() == ".gif":
        return GifWriter(out, fps)
    try:
        from imageio_ffmpeg import write_frames  # the video extra
    except ImportError:
        raise ValueError(
            f"recording MP4 needs the '{VIDEO_EXTRA}' extra: pip install 'mrcomm-env[{VIDEO_EXTRA}]' (or record a .gif)"
        ) from None
    return Mp4Writer(out, fps, write_frames)
