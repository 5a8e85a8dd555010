"""Train PPO on CartPoleBalance-v0 (2 worker processes), export ONNX with metadata, play it with onnxruntime.

    pip install -e .[train]          # torch==2.13.0 CPU, stable-baselines3, onnx, onnxruntime, tqdm, rich
    python examples/train_and_play_cartpole.py --timesteps 60000 --video runs/cartpole/play.mp4

Same as ``giwbc train --env giwbc/CartPoleBalance-v0 --timesteps 60000 --n-envs 2`` then
``giwbc play --policy runs/cartpole/policy.onnx --video runs/cartpole/play.mp4`` (the video needs EGL or
OSMesa, libegl1 or libosmesa6, found when it renders).
"""

from __future__ import annotations

import argparse
import json

from giwbc.apps.play import play
from giwbc.policy import OnnxPolicy
from giwbc.apps.training import TrainConfig, train


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--timesteps", type=int, default=60_000)
    parser.add_argument("--out", default="runs/cartpole")
    parser.add_argument("--video", default=None)
    args = parser.parse_args()

    result = train(TrainConfig(env_id="giwbc/CartPoleBalance-v0", total_timesteps=args.timesteps, n_envs=2,
                               out_dir=args.out, checkpoint_every=20_000, ppo={"n_steps": 1024, "batch_size": 256}))
    policy = OnnxPolicy(result.policy)
    print("policy metadata:", json.dumps({k: policy.metadata[k] for k in ("env_id", "joint_names", "action_scale", "rates")}))
    played = play(result.policy, episodes=3, video=args.video)
    print(f"returns with onnxruntime: {played.returns}" + (f", video {played.video}" if played.video else ""))


if __name__ == "__main__":
    main()
