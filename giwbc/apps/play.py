"""``giwbc play``: run an exported ONNX policy in simulation (onnxruntime only), optionally to a video."""

from __future__ import annotations

import json
import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from giwbc.apps.arguments import POLICY_HELP, add_command, integer, number, policy_file, seed
from giwbc.apps.progress import Progress, add_progress_argument, wants_progress
from giwbc.errors import ConfigError, PolicyFormatError, RenderingUnavailableError
from giwbc.policy import OnnxPolicy
from giwbc.runtimes.rendering import offscreen_backend


@dataclass(frozen=True)
class PlayResult:
    """What :func:`play` did: per-episode returns and lengths, and the video written, if any."""

    returns: tuple[float, ...]
    lengths: tuple[int, ...]
    video: Path | None = None
    endings: tuple[str, ...] = ()  # per episode: "terminated" (fell), "time limit" (truncated) or "max steps" (--max-steps)


def play(
    policy_path: str | os.PathLike[str],
    *,
    episodes: int = 1,
    seed: int = 0,
    max_steps: int | None = None,
    video: str | os.PathLike[str] | None = None,
    real_time_factor: float | None = None,
    render_size: tuple[int, int] = (480, 640),
    env_overrides: dict[str, Any] | None = None,
    progress: bool = False,
) -> PlayResult:
    """Run a policy file in simulation for ``episodes`` episodes, optionally writing a video (.mp4 or .gif);
    ``progress``: a bar of agent steps on stderr."""
    policy = OnnxPolicy(policy_path)
    overrides = dict(env_overrides or {})
    if video is not None:
        offscreen_backend()  # before any episode runs: no GL library is a one-line error, not lost work
        overrides.update(render_mode="rgb_array", render_size=render_size)
    if real_time_factor is not None:
        overrides["real_time_factor"] = real_time_factor
    env = policy.make_env(**overrides)
    frames: list[np.ndarray] = []
    returns, lengths, endings = [], [], []
    limit = max_steps if max_steps is not None else (env.spec.max_episode_steps if env.spec is not None else None)
    bar = Progress(episodes * (limit or 0) or 0, "play", unit="step", enabled=progress and bool(limit))
    try:
        for episode in range(episodes):
            observation, _ = env.reset(seed=seed + episode)
            total, steps, done, terminated = 0.0, 0, False, False
            if video is not None:
                frames.append(env.render())
            while not done and (max_steps is None or steps < max_steps):
                observation, reward, terminated, truncated, _ = env.step(policy(observation))
                total += float(reward)
                steps += 1
                bar(1)
                done = terminated or truncated
                if video is not None:
                    frames.append(env.render())
            returns.append(total)
            lengths.append(steps)
            endings.append("terminated" if terminated else "time limit" if done else "max steps")
            bar(limit - steps if limit and done else 0)  # an episode that ended early: its unused steps
    finally:
        bar.close()
        env.close()
    written = write_video(video, frames, fps=float(policy.metadata["rates"]["agent_hz"])) if video is not None else None
    return PlayResult(tuple(returns), tuple(lengths), written, tuple(endings))


def write_video(path: str | os.PathLike[str], frames: Sequence[np.ndarray], fps: float) -> Path:
    """Write frames as an .mp4 (imageio-ffmpeg) or .gif (pillow)."""
    try:
        import imageio.v2 as imageio
    except ImportError as error:
        raise RuntimeError("writing a video needs imageio (pip install imageio imageio-ffmpeg)") from error
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() == ".gif":
        imageio.mimwrite(path, list(frames), duration=1000.0 / fps, loop=0)
    else:
        imageio.mimwrite(path, list(frames), fps=fps, macro_block_size=1)
    return path


# --- command line ------------------------------------------------------------------------------
ENDINGS = {"terminated": "terminated (fell)", "time limit": "reached its time limit", "max steps": "stopped at --max-steps"}
MAX_EPISODES = 10_000
MAX_STEPS = 1_000_000  # agent steps per episode (5.5 h at 50 Hz)
VIDEO_SUFFIXES = (".mp4", ".gif")


def add_play_command(commands: Any) -> None:
    """Add ``giwbc play`` to an argparse subparsers object."""
    parser = add_command(commands, "play", "run an exported ONNX policy in simulation (onnxruntime only)")
    parser.add_argument("--policy", required=True, type=policy_file(), help=POLICY_HELP)
    parser.add_argument("--episodes", type=integer(1, MAX_EPISODES), default=1, help=f"episodes to run, in [1, {MAX_EPISODES}]")
    parser.add_argument("--seed", type=seed(), default=0, help="seed of the first episode (the next ones: seed + 1, ...)")
    parser.add_argument("--max-steps", type=integer(1, MAX_STEPS), default=None,
                        help="stop an episode after this many agent steps (default: the environment's time limit)")
    parser.add_argument("--video", default=None, help="write a video (.mp4 or .gif); needs EGL or OSMesa (libegl1 or libosmesa6)")
    parser.add_argument("--real-time-factor", type=number(0.0, 100.0, low_open=True), default=None,
                        help="pace the simulation at this multiple of real time, in (0, 100] (default: as fast as possible)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    add_progress_argument(parser)
    parser.set_defaults(run=run_play_command)


def run_play_command(args: Any) -> int:
    if args.video is not None and Path(args.video).suffix.lower() not in VIDEO_SUFFIXES:
        raise ConfigError(f"--video {args.video}: expected a {' or '.join(VIDEO_SUFFIXES)} file")
    try:
        result = play(args.policy, episodes=args.episodes, seed=args.seed, max_steps=args.max_steps, video=args.video,
                      real_time_factor=args.real_time_factor, progress=wants_progress(args))
    except (PolicyFormatError, FileNotFoundError, RenderingUnavailableError) as error:
        print(f"giwbc play: error: {error}", file=sys.stderr)
        return 2
    summary = {"returns": list(result.returns), "lengths": list(result.lengths), "endings": list(result.endings),
               "video": str(result.video) if result.video else None}
    if args.json:
        print(json.dumps(summary))
    else:
        for index, (ret, length, ending) in enumerate(zip(result.returns, result.lengths, result.endings)):
            print(f"episode {index}: return {ret:.2f} over {length} steps: {ENDINGS[ending]}")
        if result.video:
            print(f"video: {result.video}")
    return 0
