"""Every ``giwbc`` subcommand against bad input: every numeric option (found by walking
:func:`giwbc.apps.cli.build_parser`, so a new option is covered the day it is added) with nan, inf,
-inf, -1, 0 and 1e12, and every file option with a missing, empty, wrong-kind and corrupted file.

Each case ends with exit 0 or 2 within a bounded time, never a traceback, and an exit 2 says why in
one line on stderr. A value argparse refuses costs one parse; a value it accepts is then run for real
with cheap base arguments and must end quickly. A ``giwbc deploy`` that exits 2 never enabled a
motor (its log, when it wrote one, holds no ``enter`` frame). Numeric options must be typed by
:mod:`giwbc.apps.arguments` (an option still typed plain ``float``/``int`` fails)."""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import shutil
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from giwbc.apps.cli import build_parser, main

ROOT = Path(__file__).resolve().parents[1]
BALANCE_POLICY = ROOT / "policies" / "g1_balance_residual.onnx"
WALK_POLICY = ROOT / "policies" / "g1_walk_residual.onnx"
VALUES = ("nan", "inf", "-inf", "-1", "0", "1e12")
RUN_TIMEOUT_S = 120  # one accepted-value run, wall clock (each takes a few seconds)
SUBPROCESS = ("deploy", "motors", "train")  # spawn processes or own signals: run as `python -m giwbc.apps.cli`
OTHER_HELPERS = ("deploy", "motors", "train")  # validated by their own modules (giwbc.apps.deploy*, motors, training)
PENDING: tuple[str, ...] = ()  # their validation is being fixed concurrently: xfail(strict=False) until it lands

# Cheap base arguments per command: a value the parser accepts runs with these (the swept option's
# value comes last, so it wins over a base value of the same option). {tmp}: the case's folder.
BASE: dict[tuple[str, ...], list[str]] = {
    ("robots",): [],
    ("sim",): ["--seconds", "0.05"],
    ("demo",): ["--no-video"],  # every value --seconds accepts runs the whole demo: none of VALUES is accepted
    ("walk",): ["--seconds", "0.1"],
    ("play",): ["--policy", str(BALANCE_POLICY), "--max-steps", "2"],
    ("evaluate",): ["--episodes", "1", "--interval", "0.6", "0.65", "--workers", "1"],  # episodes: the push's end + 3 s
    ("sim-to-sim",): ["--episodes", "1", "--seconds", "0.1", "--workers", "0", "--conditions", "mujoco_nominal", "--no-policy"],
    ("deploy",): ["--robot", "g1", "--emulate", "--seconds", "0.1", "--unpaced", "--controller", "pd", "--ramp", "0.2",
                  "--scene-rate", "0", "--log", "{tmp}/run.mcap"],
    ("motors", "check"): ["--dry-run"],
    ("motors", "scan"): ["--dry-run", "--ids", "1-4", "--hardware", "{tmp}/hardware.toml"],
    ("motors", "monitor"): ["--dry-run", "--count", "1", "--hardware", "{tmp}/hardware.toml"],
    ("motors", "zero"): ["left_knee_joint", "--dry-run", "--yes", "--hardware", "{tmp}/hardware.toml"],
    ("motors", "calibrate"): ["--dry-run", "--yes", "--joints", "left_knee_joint", "--hardware", "{tmp}/hardware.toml"],
    ("train",): ["--env", "giwbc/CartPoleBalance-v0", "--timesteps", "64", "--n-envs", "1", "--vectorization", "dummy",
                 "--ppo", '{"n_steps": 32, "batch_size": 32, "n_epochs": 1}', "--out", "{tmp}/train", "--no-progress"],
    ("log", "plot"): ["{tmp}/missing.mcap"],  # replaced by a real log when the option under test is not the log itself
}
# Values that mean "until Ctrl-C": run, interrupted after a few seconds, they must end cleanly (0 or 130).
OPEN_ENDED = {(("motors", "monitor"), "--count", "0")}
INTERRUPT_AFTER_S = 4.0
# The file options: (command, option) -> kind of file. Options typed `existing_file` are found on their own.
FILE_OPTIONS: dict[tuple[tuple[str, ...], str], str] = {
    (("deploy",), "--policy"): "policy",
    (("deploy",), "--hardware"): "hardware",
    (("deploy",), "--emulated-hardware"): "hardware",
    (("train",), "--resume"): "checkpoint",
    (("train",), "--warm-start"): "policy",
    **{(("motors", action), option): "hardware" for action in ("check", "scan", "monitor", "zero", "calibrate")
       for option in ("--hardware", "--dry-run-plan")},
}
SUFFIX = {"policy": ".onnx", "hardware": ".toml", "log": ".mcap", "checkpoint": ".zip"}


def _commands(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()) -> Iterator[tuple[tuple[str, ...], argparse.ArgumentParser]]:
    """Every leaf subcommand: (its words, its parser)."""
    subparsers = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subparsers:
        yield path, parser
    for action in subparsers:
        for name, child in action.choices.items():
            yield from _commands(child, (*path, name))


def _is_file_type(kind: object) -> bool:
    return getattr(kind, "__module__", "") == "giwbc.apps.arguments" and getattr(kind, "__qualname__", "").startswith(("existing_file", "policy_file"))


def _is_number_type(kind: object) -> bool:
    return getattr(kind, "__module__", "") == "giwbc.apps.arguments" and getattr(kind, "__qualname__", "").startswith("number")


PARSER = build_parser()
COMMANDS = dict(_commands(PARSER))
TYPED = [(path, action) for path, parser in COMMANDS.items() for action in parser._actions
         if action.type is not None and action.type is not str and not _is_file_type(action.type)]
NUMERIC = [(path, action) for path, action in TYPED if action.option_strings]
FILES = {**{(path, action.option_strings[0] if action.option_strings else action.dest): "log" if path == ("log", "plot") else "policy"
            for path, parser in COMMANDS.items() for action in parser._actions if _is_file_type(action.type)},
         **{key: kind for key, kind in FILE_OPTIONS.items() if key[0] in COMMANDS and key[1] in COMMANDS[key[0]]._option_string_actions}}


def _marks(path: tuple[str, ...]) -> list[pytest.MarkDecorator]:
    if path[0] in PENDING:
        return [pytest.mark.xfail(strict=False, reason="fixed by deploy/motors/train validation work")]
    return []


def _name(action: argparse.Action) -> str:
    return action.option_strings[-1] if action.option_strings else action.dest


# --- running a command ----------------------------------------------------------------------------
class _Alarm(Exception):
    pass


def _in_process(argv: list[str]) -> tuple[int, str, str]:
    """``main(argv)`` with stdout/stderr captured and a wall-clock alarm."""
    out, err = io.StringIO(), io.StringIO()

    def ring(*_: object) -> None:
        raise _Alarm(f"{argv} ran past {RUN_TIMEOUT_S} s")

    previous = signal.signal(signal.SIGALRM, ring)
    signal.alarm(RUN_TIMEOUT_S)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = main(argv)
            except SystemExit as stop:
                code = stop.code if isinstance(stop.code, int) else 2
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    return int(code), out.getvalue(), err.getvalue()


def _subprocess(argv: list[str], cwd: Path) -> tuple[int, str, str]:
    environment = {**os.environ, "MPLBACKEND": "Agg", "PYTHONPATH": str(ROOT)}
    done = subprocess.run([sys.executable, "-m", "giwbc.apps.cli", *argv], cwd=cwd, capture_output=True, text=True,
                          timeout=RUN_TIMEOUT_S, stdin=subprocess.DEVNULL, env=environment)
    return done.returncode, done.stdout, done.stderr


def _interrupted(argv: list[str], cwd: Path) -> tuple[int, str, str]:
    """Run an open-ended command, Ctrl-C it after INTERRUPT_AFTER_S: 130 (or 0) is a clean end, reported as 0."""
    code, out, err = _interrupted_raw(argv, cwd)
    assert code in (0, 2, 130), f"{argv}: Ctrl-C gave exit {code}: {err[-2000:]}"
    return (0 if code == 130 else code), out, err


def _interrupted_raw(argv: list[str], cwd: Path) -> tuple[int, str, str]:
    """Run ``giwbc argv`` (SIGINT at its default, whatever the caller ignores); once it has printed its
    first line (it is past its imports and checks: a Ctrl-C before that is Python's own), Ctrl-C it."""
    import threading

    environment = {**os.environ, "MPLBACKEND": "Agg", "PYTHONPATH": str(ROOT)}
    process = subprocess.Popen([sys.executable, "-m", "giwbc.apps.cli", *argv], cwd=cwd, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True, env=environment,
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    streams: dict[str, list[str]] = {"out": [], "err": []}
    started = threading.Event()

    def read(stream: io.TextIOBase, into: list[str]) -> None:
        for line in stream:
            into.append(line)
            started.set()

    readers = [threading.Thread(target=read, args=(process.stdout, streams["out"]), daemon=True),
               threading.Thread(target=read, args=(process.stderr, streams["err"]), daemon=True)]
    for reader in readers:
        reader.start()
    try:
        started.wait(RUN_TIMEOUT_S)
        if process.poll() is None:
            try:
                process.wait(INTERRUPT_AFTER_S)
            except subprocess.TimeoutExpired:
                process.send_signal(signal.SIGINT)
        process.wait(30)
    finally:
        process.kill()
        for reader in readers:
            reader.join(5)
    return process.returncode, "".join(streams["out"]), "".join(streams["err"])


def _prepare(tmp: Path) -> None:
    """What base arguments point at: a copy of the shipped hardware plan (a zero or calibrate could write it)."""
    shutil.copy(ROOT / "robots" / "g1" / "hardware.toml", tmp / "hardware.toml")


def _run(path: tuple[str, ...], argv: list[str], tmp: Path, isolated: bool = True) -> tuple[int, str, str]:
    """Run a command: in a subprocess for those in SUBPROCESS when ``isolated``, else in this process."""
    _prepare(tmp)
    if isolated and path[0] in SUBPROCESS:
        return _subprocess(argv, tmp)
    cwd = Path.cwd()
    os.chdir(tmp)  # anything written by default (runs/, videos) lands in the case's folder
    try:
        return _in_process(argv)
    finally:
        os.chdir(cwd)


def _check_outcome(path: tuple[str, ...], argv: list[str], code: int, out: str, err: str, tmp: Path) -> None:
    assert code in (0, 2), f"{argv}: exit {code}\nstdout: {out[-2000:]}\nstderr: {err[-2000:]}"
    assert "Traceback" not in err + out, f"{argv}: {err[-3000:]}"
    if code == 2:
        lines = [line for line in err.splitlines() if line.strip()]
        assert len(lines) == 1, f"{argv}: exit 2 must say why in one line, got {lines}"
        assert "error" in lines[0] and "error" not in out.lower(), f"{argv}: the error goes to stderr only: {out!r}"
        if path[0] == "deploy":
            _assert_no_motor_enabled(tmp / "run.mcap")


def _assert_no_motor_enabled(log: Path) -> None:
    """A refused deploy never enabled a motor: no log, or a log without an ``enter`` (enable) frame."""
    if not log.exists():
        return
    from giwbc.runlog import read_log

    kinds = {m.get("kind") for m in read_log(log, topics=["/commands"]).topic("/commands")}
    assert "enter" not in kinds, f"a deploy that exited 2 enabled the motors ({log})"


def _parse(argv: list[str]) -> tuple[int | None, str]:
    """Parse only: None when the parser accepts, else its exit code and stderr."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            build_parser().parse_args(argv)
        except SystemExit as stop:
            return int(stop.code), err.getvalue()
    return None, ""


def _namespace(argv: list[str]) -> dict[str, object]:
    return {key: value for key, value in vars(build_parser().parse_args(argv)).items() if key != "run"}


def _base(path: tuple[str, ...], tmp: Path, real_log: Path | None = None) -> list[str]:
    base = [arg.replace("{tmp}", str(tmp)) for arg in BASE[path]]
    if path == ("log", "plot") and real_log is not None:
        base = [str(real_log), "-o", str(tmp / "report.png")]
    return base


# --- the sweep ------------------------------------------------------------------------------------
def test_every_command_has_cheap_base_arguments():
    assert set(COMMANDS) <= set(BASE), f"add base arguments for {sorted(set(COMMANDS) - set(BASE))}"
    assert len(NUMERIC) > 40  # the walk found the options (every command has some)
    assert (("play",), "--policy") in FILES and (("log", "plot"), "log") in FILES and (("deploy",), "--hardware") in FILES


@pytest.mark.parametrize("path, action", [pytest.param(p, a, marks=_marks(p), id=f"{' '.join(p)} {_name(a)}") for p, a in TYPED])
def test_every_numeric_option_is_typed_by_the_shared_argument_types(path, action):
    """float/int let nan, inf and negative values through to the controllers: every number must
    carry its range and unit (giwbc.apps.arguments.number / integer / seconds)."""
    assert action.type not in (float, int), f"giwbc {' '.join(path)} {_name(action)} is typed plain {action.type.__name__}"
    if _is_number_type(action.type):
        assert action.help and action.help.strip(), f"giwbc {' '.join(path)} {_name(action)} has no help (unit, range)"


@pytest.mark.slow
@pytest.mark.parametrize("path", [pytest.param(p, marks=_marks(p), id=" ".join(p)) for p in COMMANDS if p != ("demo",)])
def test_the_base_arguments_run_clean(path, tmp_path, real_log):
    """The sweep's base arguments are valid and cheap: otherwise every accepted value would exit 2 for
    the base's sake and the sweep would prove nothing. (demo: its base runs the whole demo, and no swept
    value reaches a run.)"""
    argv = [*path, *_base(path, tmp_path, real_log)]
    code, out, err = _run(path, argv, tmp_path)
    assert code == 0, f"{argv}: exit {code}\n{out[-2000:]}\n{err[-2000:]}"


CASES = [pytest.param(p, a, v, marks=_marks(p), id=f"{' '.join(p)} {_name(a)} {v}") for p, a in NUMERIC for v in VALUES]


@pytest.mark.parametrize("path, action, value", CASES)
def test_a_bad_number_is_refused_in_one_line_or_runs_and_ends(path, action, value, tmp_path, real_log):
    nargs = action.nargs if isinstance(action.nargs, int) else 1
    argv = [*path, *_base(path, tmp_path, real_log), action.option_strings[0], *[value] * nargs]
    code, err = _parse(argv)
    if code is not None:  # refused while parsing: nothing started
        assert code == 2 and "Traceback" not in err
        assert len(err.strip().splitlines()) == 1, f"{argv}: {err}"
        assert action.option_strings[0] in err or _name(action) in err, err
        return
    if _namespace(argv) == _namespace([*path, *_base(path, tmp_path, real_log)]):
        return  # the value is the option's default: the base run (test_the_base_arguments_run_clean) is this run
    if (path, action.option_strings[0], value) in OPEN_ENDED:
        _prepare(tmp_path)
        _check_outcome(path, argv, *_interrupted(argv, tmp_path), tmp_path)
        return
    _check_outcome(path, argv, *_run(path, argv, tmp_path), tmp_path)


# --- files ----------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def real_log(tmp_path_factory) -> Path:
    """A small run log as `giwbc deploy` writes it (for the log command's base arguments)."""
    from giwbc.robot import load
    from giwbc.runlog import RunLogWriter

    g1 = load("g1")
    path = tmp_path_factory.mktemp("log") / "run.mcap"
    n = len(g1.joint_names)
    with RunLogWriter(path, g1.joint_names, {"robot": "g1", "task": "stand", "controller": "pd", "control_rate": 500.0}) as log:
        for cycle in range(20):
            t = 0.002 * cycle
            if cycle == 0:
                log.event(cycle, t, "phase", {"phase": "running"})
            log.commands(cycle, t, "running", "command", np.zeros(n), np.zeros(n), np.zeros(n), np.ones(n), np.zeros(n))
            log.replies(cycle, t, np.zeros(n), np.zeros(n), np.zeros(n), np.full(n, 30.0), np.zeros(n), np.zeros(n, bool), 0, 0, 0)
            log.timing(cycle, t, cycle, 10.0, None if cycle == 0 else 2000.0, 400.0, 50.0, 50.0, False)
            log.flush()
    return path


@pytest.fixture(scope="module")
def wrong_files(tmp_path_factory) -> dict[str, Path]:
    """Readable files of the right suffix but the wrong kind: a CartPole policy, a robot.toml where a hardware plan
    is expected, a policy where a run log is, a zip that is no checkpoint."""
    import zipfile

    from giwbc.apps.training import describe_env
    from giwbc.policy import MlpWeights, export_onnx

    folder = tmp_path_factory.mktemp("wrong")
    env_id = "giwbc/CartPoleBalance-v0"
    metadata = {**describe_env(env_id, {}), "env_id": env_id, "env_kwargs": {}}
    rng = np.random.default_rng(0)
    sizes = (len(metadata["observation_names"]), 8, len(metadata["action_names"]))
    mlp = MlpWeights(tuple((rng.normal(0, 0.5, (o, i)), rng.normal(0, 0.1, o)) for i, o in zip(sizes[:-1], sizes[1:])))
    policy = export_onnx(folder / "cartpole.onnx", mlp, metadata)
    hardware = folder / "robot.toml"
    shutil.copy(ROOT / "robots" / "g1" / "robot.toml", hardware)
    log = folder / "policy.mcap"
    shutil.copy(BALANCE_POLICY, log)
    checkpoint = folder / "notes.zip"
    with zipfile.ZipFile(checkpoint, "w") as archive:
        archive.writestr("notes.txt", "not a checkpoint")
    return {"policy": policy, "hardware": hardware, "log": log, "checkpoint": checkpoint}


def _file(kind: str, case: str, tmp: Path, wrong_files: dict[str, Path]) -> Path:
    path = tmp / f"{case}{SUFFIX[kind]}"
    if case == "empty":
        path.write_bytes(b"")
    elif case == "corrupted":
        path.write_bytes(np.random.default_rng(7).bytes(4096))
    elif case == "wrong":
        shutil.copy(wrong_files[kind], path)
    return path  # "missing": never written


def _play_wrong_policy(tmp: Path) -> Path:
    """For `giwbc play` (which plays any environment's policy): a CartPole network whose metadata names G1Balance-v0."""
    from giwbc.apps.training import describe_env
    from giwbc.policy import MlpWeights, export_onnx

    metadata = {**describe_env("giwbc/CartPoleBalance-v0", {}), "env_id": "giwbc/G1Balance-v0", "env_kwargs": {}}
    sizes = (len(metadata["observation_names"]), len(metadata["action_names"]))
    mlp = MlpWeights(((np.zeros((sizes[1], sizes[0])), np.zeros(sizes[1])),))
    return export_onnx(tmp / "wrong.onnx", mlp, metadata)


FILE_CASES = [pytest.param(p, o, k, c, marks=_marks(p), id=f"{' '.join(p)} {o} {c}")
              for (p, o), k in sorted(FILES.items()) for c in ("missing", "empty", "wrong", "corrupted")]


@pytest.mark.parametrize("path, option, kind, case", FILE_CASES)
def test_a_bad_file_is_refused_in_one_line(path, option, kind, case, tmp_path, wrong_files, real_log):
    file = _file(kind, case, tmp_path, wrong_files)
    if path == ("play",) and case == "wrong":
        file = _play_wrong_policy(tmp_path)
    base = _base(path, tmp_path, real_log)
    if option.startswith("--"):
        argv = [*path, *base, option, str(file)]
        if option == "--dry-run-plan" and "--dry-run" not in argv:
            argv.append("--dry-run")
        if path == ("sim-to-sim",):
            argv.remove("--no-policy")
    else:  # the positional log of `giwbc log plot`
        argv = [*path, str(file), "-o", str(tmp_path / "report.png")]
    code, err = _parse(argv)
    if code is None:
        code, out, err = _run(path, argv, tmp_path, isolated=False)  # refused before any work: no process to isolate
        _check_outcome(path, argv, code, out, err, tmp_path)
    assert code == 2, f"{argv}: a {case} {kind} file must be refused (exit 2), got {code}: {err}"
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err


# --- help -----------------------------------------------------------------------------------------
@pytest.mark.parametrize("path", [pytest.param(p, marks=_marks(p), id=" ".join(p)) for p in COMMANDS])
def test_every_option_says_what_it_is(path):
    parser = COMMANDS[path]
    assert isinstance(parser.formatter_class, type) and parser.formatter_class.__name__ == "HelpFormatter"
    silent = [_name(a) for a in parser._actions if a.option_strings and a.help != argparse.SUPPRESS and not (a.help or "").strip()]
    assert not silent, f"giwbc {' '.join(path)}: options without help: {silent}"


def test_top_level_help_is_plain_text_and_there_is_a_version(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["--help"])
    out = capsys.readouterr().out
    assert stop.value.code == 0 and "``" not in out and "giwbc" in out
    with pytest.raises(SystemExit) as stop:
        main(["--version"])
    assert stop.value.code == 0 and capsys.readouterr().out.strip().startswith("giwbc 0.")


# --- what a run says ------------------------------------------------------------------------------
def test_play_says_how_each_episode_ended(tmp_path, capsys):
    """A fall (CartPole with a zero force: the pole drops), the environment's time limit (the shipped
    balance policy stands its 200 steps) and --max-steps are told apart, per episode."""
    from giwbc.apps.training import describe_env
    from giwbc.policy import MlpWeights, export_onnx

    env_id = "giwbc/CartPoleBalance-v0"
    metadata = {**describe_env(env_id, {}), "env_id": env_id, "env_kwargs": {}}
    n_obs, n_act = len(metadata["observation_names"]), len(metadata["action_names"])
    zero = export_onnx(tmp_path / "zero.onnx", MlpWeights(((np.zeros((n_act, n_obs)), np.zeros(n_act)),)), metadata)
    assert main(["play", "--policy", str(zero), "--episodes", "2", "--seed", "3"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 2 and all(line.endswith(": terminated (fell)") for line in lines), lines
    assert main(["play", "--policy", str(BALANCE_POLICY), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["endings"] == ["time limit"] and result["lengths"] == [200]
    assert main(["play", "--policy", str(BALANCE_POLICY), "--max-steps", "3"]) == 0
    out = capsys.readouterr().out.strip()
    assert out.startswith("episode 0: return ") and out.endswith(" over 3 steps: stopped at --max-steps"), out


def test_ctrl_c_ends_a_simulation_in_one_line_with_exit_130(tmp_path):
    pytest.importorskip("foxglove")  # its first line (where to connect) says the walk has started
    code, out, err = _interrupted_raw(["walk", "--seconds", "600", "--foxglove", "--foxglove-port", "18733"], tmp_path)
    assert code == 130 and err.strip().splitlines()[-1] == "giwbc walk: interrupted" and "Traceback" not in err, err
    assert len(err.strip().splitlines()) == 2  # where to connect, then the interruption
