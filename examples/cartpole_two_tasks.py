"""One robot, two tasks (the Gym-Ignition paper's example): a hand-written energy + LQR-like controller
acting through the same normalized cart-force action on CartPoleBalance-v0 and CartPoleSwingUp-v0.

    python examples/cartpole_two_tasks.py
"""

from __future__ import annotations

import math

import giwbc  # noqa: F401  (before numpy: it pins the floating-point kernels, giwbc.numerics)
import gymnasium
import numpy as np

import giwbc.envs  # noqa: F401  (registers the giwbc/ ids)


def controller(observation: np.ndarray) -> np.ndarray:
    """Pump energy while the pole is low, balance with state feedback near the top."""
    x, x_dot, cos_theta, sin_theta, theta_dot = observation.astype(float)
    theta = math.atan2(sin_theta, cos_theta)
    if cos_theta > 0.85:  # near upright: push the cart under the pole
        force = 30.0 * theta + 5.0 * theta_dot + 1.0 * x + 2.0 * x_dot
    else:  # swing: energy pumping along the pole's velocity
        energy = 0.5 * (0.2 * 0.25**2 + 0.0041708) * theta_dot**2 + 0.2 * 9.81 * 0.25 * (cos_theta - 1.0)
        force = 40.0 * energy * np.sign(theta_dot * cos_theta) - 2.0 * x - 1.0 * x_dot
    return np.array([np.clip(force / 20.0, -1.0, 1.0)], dtype=np.float32)


def main() -> None:
    for env_id in ("giwbc/CartPoleBalance-v0", "giwbc/CartPoleSwingUp-v0"):
        env = gymnasium.make(env_id)
        observation, _ = env.reset(seed=0)
        total, steps, done = 0.0, 0, False
        while not done:
            observation, reward, terminated, truncated, _ = env.step(controller(observation))
            total, steps, done = total + float(reward), steps + 1, terminated or truncated
        print(f"{env_id}: return {total:.1f} over {steps} steps ({'terminated' if terminated else 'time limit'})")
        env.close()


if __name__ == "__main__":
    main()
