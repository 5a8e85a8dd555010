"""``make demo``: G1 in MuJoCo, headless, with printed metrics."""

from __future__ import annotations

from giwbc.cli import run_pd_hold


def run_demo(seconds: float = 10.0) -> int:
    """Stand G1 with a joint-PD hold and report; grows as the controller stack lands."""
    print("giwbc demo: Unitree G1 (29 DoF) in MuJoCo, joint-PD hold at the default pose")
    summary = run_pd_hold("g1", seconds)
    print(f"  simulated {summary.seconds:.1f} s in {summary.wall_seconds:.2f} s (real-time factor {summary.real_time_factor:.1f})")
    print(f"  base height {summary.min_base_height:.3f}..{summary.max_base_height:.3f} m, max tilt {summary.max_tilt_deg:.2f} deg")
    print(f"  contact force {summary.vertical_contact_force:.1f} N vs weight {summary.weight:.1f} N")
    return 0 if summary.stood else 1
