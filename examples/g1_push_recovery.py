"""G1Balance-v0 with zero residual: the whole-body controller alone under random pushes.

    python examples/g1_push_recovery.py --seconds 10 --video g1.mp4   # video: EGL or OSMesa, found when it renders

Prints, per episode, how long the robot stood and how many pushes it took; the baseline a
residual policy trained on this environment has to beat.
"""

from __future__ import annotations

import argparse

import giwbc  # noqa: F401  (before numpy: it pins the floating-point kernels, giwbc.numerics)
import gymnasium
import numpy as np

import giwbc.envs  # noqa: F401  (registers the giwbc/ ids)
from giwbc.apps.play import write_video


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--episodes", type=int, default=2)
    parser.add_argument("--controller", choices=("wbc", "pd"), default="wbc")
    parser.add_argument("--video", default=None, help=".mp4 or .gif of the first episode")
    args = parser.parse_args()

    env = gymnasium.make("giwbc/G1Balance-v0", controller=args.controller, render_mode="rgb_array" if args.video else None,
                         controller_rate=500.0 if args.controller == "wbc" else 50.0)
    zero = np.zeros(env.action_space.shape, dtype=np.float32)
    frames = []
    for episode in range(args.episodes):
        env.reset(seed=episode)
        info, terminated = {}, False
        for _ in range(int(args.seconds * env.unwrapped.rates.agent)):
            _, _, terminated, truncated, info = env.step(zero)
            if args.video and episode == 0:
                frames.append(env.render())
            if terminated or truncated:
                break
        status = "fell" if terminated else "stood"
        print(f"episode {episode}: {status} for {info['time']:.2f} s, {info.get('pushes', 0)} pushes")
    env.close()
    if args.video:
        print("video:", write_video(args.video, frames, fps=env.unwrapped.rates.agent))


if __name__ == "__main__":
    main()
