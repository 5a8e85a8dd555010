"""Offscreen OpenGL for MuJoCo rendering, chosen when something renders and never at import.

``import mujoco`` with ``MUJOCO_GL=osmesa`` loads the OSMesa context at import time and crashes on a
machine without ``libOSMesa``; with ``MUJOCO_GL`` unset it imports fine and picks GLFW, which needs
a display. giwbc therefore never sets ``MUJOCO_GL`` itself. When a frame is first rendered
(``render_mode="rgb_array"``, ``giwbc play --video``), :func:`offscreen_backend` honours a
``MUJOCO_GL`` the user set before ``import mujoco``; otherwise it probes EGL, then OSMesa, each in
a child process (a failed GL load leaves PyOpenGL unusable in the process that tried), and
installs the first that works as MuJoCo's context class. With neither, it raises
:class:`RenderingUnavailableError` naming the package to install.

``render_mode="human"`` opens MuJoCo's viewer (``mujoco.viewer.launch_passive``, a GLFW window).
Where GLFW cannot start, MuJoCo prints ``could not initialize GLFW`` and ends the whole process,
past any ``except``; :func:`require_display` therefore checks first, without touching GLFW in this
process: no ``DISPLAY`` / ``WAYLAND_DISPLAY`` on Linux, or a child process that cannot initialize
GLFW and open a hidden OpenGL window, is a :class:`RenderingUnavailableError`.
"""

from __future__ import annotations

import os
import subprocess
import sys
from typing import Any

from giwbc.errors import RenderingUnavailableError

# Offscreen backends in order of preference, with the Debian/Ubuntu package that provides each.
OFFSCREEN_BACKENDS: dict[str, str] = {"egl": "libegl1", "osmesa": "libosmesa6"}
_PROBE = "import mujoco; c = mujoco.GLContext(8, 8); c.make_current(); c.free()"


def probe_backend(backend: str, timeout: float = 60.0) -> str | None:
    """Try ``backend`` in a child process: ``None`` when it creates a context, else the reason it failed."""
    if backend not in OFFSCREEN_BACKENDS:
        raise ValueError(f"unknown offscreen GL backend {backend!r}; expected one of {sorted(OFFSCREEN_BACKENDS)}")
    env = {**os.environ, "MUJOCO_GL": backend}
    env.pop("PYOPENGL_PLATFORM", None)
    try:
        result = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True,
                                timeout=timeout)
    except subprocess.TimeoutExpired:
        return f"probing {backend} timed out after {timeout:.0f} s"
    if result.returncode == 0:
        return None
    lines = result.stderr.strip().splitlines()
    return lines[-1] if lines else f"exit code {result.returncode}"


# A hidden GLFW window, as the viewer opens a visible one; exits non-zero with the reason on stderr.
_WINDOW_PROBE = """
import sys
import glfw
reasons = []
glfw.set_error_callback(lambda code, text: reasons.append(text.decode(errors="replace")))
if not glfw.init():
    sys.exit("GLFW cannot initialize: " + ("; ".join(reasons) or "no reason given"))
glfw.window_hint(glfw.VISIBLE, glfw.FALSE)
window = glfw.create_window(16, 16, "giwbc display probe", None, None)
if not window:
    glfw.terminate()
    sys.exit("GLFW cannot open an OpenGL window: " + ("; ".join(reasons) or "no reason given"))
glfw.destroy_window(window)
glfw.terminate()
"""
_WINDOWED_PLATFORMS = ("linux", "freebsd", "openbsd", "netbsd")  # X11 or Wayland: a display named in the environment


def display_problem() -> str | None:
    """Why no window can open here, as far as the environment tells (no GL touched): ``None`` when one may."""
    if sys.platform.startswith(_WINDOWED_PLATFORMS) and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return "no display (DISPLAY and WAYLAND_DISPLAY are unset: a headless machine)"
    return None


def probe_window(timeout: float = 30.0) -> str | None:
    """Initialize GLFW and open a hidden OpenGL window in a child process: ``None`` when it works, else why not."""
    try:
        result = subprocess.run([sys.executable, "-c", _WINDOW_PROBE], capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return f"opening a GLFW window timed out after {timeout:.0f} s"
    if result.returncode == 0:
        return None
    lines = result.stderr.strip().splitlines()
    return lines[-1] if lines else f"the GLFW probe exited with code {result.returncode}"


def require_display() -> None:
    """Raise :class:`RenderingUnavailableError` unless MuJoCo's viewer can open a window here
    (``render_mode="human"``); MuJoCo itself would end the process instead."""
    problem = display_problem() or probe_window()
    if problem is not None:
        raise RenderingUnavailableError(
            f"render_mode='human' needs a display for MuJoCo's viewer: {problem}; use render_mode='rgb_array' "
            "(offscreen frames) or run inside a desktop session (or xvfb-run)"
        )


def find_offscreen_backend() -> str:
    """The first offscreen backend that works on this machine (EGL, then OSMesa), else a clear error."""
    reasons = {backend: probe_backend(backend) for backend in OFFSCREEN_BACKENDS}
    for backend, reason in reasons.items():
        if reason is None:
            return backend
    raise RenderingUnavailableError(
        "rendering needs an offscreen OpenGL library and none was found (EGL: "
        f"{reasons['egl']}; OSMesa: {reasons['osmesa']}): install one, e.g. "
        "`apt-get install libegl1` or `apt-get install libosmesa6`, or set MUJOCO_GL before starting"
    )


def _context_backend(gl_context: Any) -> str | None:
    """Which offscreen backend MuJoCo's context class belongs to (None for GLFW or none)."""
    module = getattr(getattr(gl_context, "GLContext", None), "__module__", "") or ""
    return next((backend for backend in OFFSCREEN_BACKENDS if module.startswith(f"mujoco.{backend}")), None)


def offscreen_backend() -> str:
    """Make MuJoCo's renderer use a working offscreen backend, chosen now, and return its name.

    A ``MUJOCO_GL`` set before ``import mujoco`` is the user's choice and is kept. Otherwise the
    backend is probed and its context class installed where ``mujoco.Renderer`` looks for it, the
    same class ``MUJOCO_GL`` would have selected at import.
    """
    import mujoco  # noqa: F401  (the context module below is part of it)
    from mujoco.rendering.classic import gl_context

    chosen_at_import = getattr(gl_context, "_MUJOCO_GL", "")
    if chosen_at_import:
        return chosen_at_import
    current = _context_backend(gl_context)
    if current is not None:
        return current
    backend = find_offscreen_backend()
    os.environ.setdefault("PYOPENGL_PLATFORM", backend)
    if os.environ["PYOPENGL_PLATFORM"] != backend:
        raise RenderingUnavailableError(
            f"PYOPENGL_PLATFORM={os.environ['PYOPENGL_PLATFORM']!r} conflicts with the {backend} backend; "
            f"unset it or set MUJOCO_GL={os.environ['PYOPENGL_PLATFORM']}"
        )
    if backend == "egl":
        from mujoco.egl import GLContext
    else:
        from mujoco.osmesa import GLContext
    gl_context.GLContext = GLContext
    return backend


def offscreen_renderer(model: Any, height: int, width: int) -> Any:
    """A ``mujoco.Renderer`` on an offscreen backend chosen now (see :func:`offscreen_backend`)."""
    import mujoco

    offscreen_backend()
    model.vis.global_.offheight = max(model.vis.global_.offheight, height)
    model.vis.global_.offwidth = max(model.vis.global_.offwidth, width)
    try:
        return mujoco.Renderer(model, height, width)
    except Exception as error:  # a library present but unusable (no device, broken driver)
        raise RenderingUnavailableError(f"cannot create an offscreen MuJoCo renderer: {error}") from error
