"""A stable-baselines3 ``VecEnv`` whose environments live in Ray actors, on one machine or a cluster.

Built like ``SubprocVecEnv``, from a list of environment constructors (what ``make_vec_env`` passes
to its ``vec_env_cls``), so seeding is the same: the constructors seed the action spaces
(``seed + rank``), :meth:`VecEnv.seed` the first reset. Each actor holds a contiguous group of the
environments (``envs_per_worker``) and steps them in order, with ``SubprocVecEnv``'s auto-reset
and info conventions; N environments therefore give bit-identical rollouts on N Ray workers (or
fewer, each holding several) and on N subprocesses.

Steps do not go through Ray's task calls (each ~0.8 ms quiet, ~1-2 ms on a loaded 2-vCPU machine,
against ~0.1 ms for a ``SubprocVecEnv`` pipe round trip): by default (``transport="channel"``) each
actor opens a persistent, authenticated ``multiprocessing.connection`` channel (TCP, to the node
address Ray gives it) that the driver sends actions and receives results over, as ``SubprocVecEnv``
does over its pipes; Ray still places, starts, monitors and stops the actors. ``"calls"``: one actor
call per actor and step (no port beyond Ray's own). ``benchmarks/scale_out.py`` measures both. (A Ray
compiled graph was tried too: fast on idle cores, but its channel readers poll, and on the loaded
2-vCPU machine a step took ~7 ms.) Resets, attributes and methods are ordinary actor calls; they
never run at the same time as a step (the driver waits for each), so the envs need no lock.

An actor that dies (its process killed, its node lost) is not restarted -- its environments'
states are gone and the rollout could not continue identically -- and that call and every later one
fails with :class:`~giwbc.errors.WorkerLostError` naming the environments lost.
"""

from __future__ import annotations

import secrets
import threading
from collections.abc import Callable, Sequence
from multiprocessing.connection import Client, Connection, Listener
from typing import Any, NoReturn

import gymnasium as gym
import numpy as np
from stable_baselines3.common.env_util import is_wrapped
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvObs, VecEnvStepReturn
from stable_baselines3.common.vec_env.subproc_vec_env import _stack_obs

from giwbc.distributed.cluster import first_line, require_ray, system_failures
from giwbc.errors import UnavailableError, WorkerLostError


TRANSPORTS = ("channel", "calls")


class EnvWorker:
    """One Ray actor's environments: stepped in order, reset after ``done`` as ``SubprocVecEnv`` does."""

    def __init__(self, env_fns: Sequence[Callable[[], gym.Env]]) -> None:
        try:
            import torch

            torch.set_num_threads(1)  # the constructors may import torch (SB3's Monitor): keep it off the other cores
        except ImportError:
            pass
        self.envs = [env_fn() for env_fn in env_fns]

    def spaces(self) -> tuple[gym.Space, gym.Space]:
        return self.envs[0].observation_space, self.envs[0].action_space

    def ping(self) -> bool:
        """A no-op call: does this actor still answer?"""
        return True

    def step(self, actions: Sequence[Any]) -> list[tuple[Any, ...]]:
        results = []
        for env, action in zip(self.envs, actions, strict=True):
            observation, reward, terminated, truncated, info = env.step(action)
            done = terminated or truncated
            info["TimeLimit.truncated"] = truncated and not terminated
            reset_info: dict[str, Any] = {}
            if done:
                info["terminal_observation"] = observation
                observation, reset_info = env.reset()
            results.append((observation, reward, done, info, reset_info))
        return results

    def open_channel(self, authkey: bytes) -> tuple[str, int]:
        """Listen on this node's address for the driver's one connection; a thread then serves steps over it
        (``(True, results)`` or ``(False, exception)`` per step) until the driver closes it."""
        import ray  # we run inside a Ray actor: ray is there

        listener = Listener((ray.util.get_node_ip_address(), 0), authkey=authkey)
        threading.Thread(target=self._serve, args=(listener,), name="giwbc-env-channel", daemon=True).start()
        return listener.address

    def _serve(self, listener: Listener) -> None:
        with listener, listener.accept() as channel:
            while True:
                try:
                    actions = channel.recv()
                except (EOFError, OSError):
                    return  # the driver closed the channel (or went away)
                try:
                    reply: tuple[bool, Any] = (True, self.step(actions))
                except Exception as error:  # the env's own error: the driver raises it, as for an actor call
                    reply = (False, error)
                channel.send(reply)

    def reset(self, seeds: Sequence[int | None], options: Sequence[dict[str, Any]]) -> list[tuple[Any, dict[str, Any]]]:
        return [env.reset(seed=seed, **({"options": option} if option else {}))
                for env, seed, option in zip(self.envs, seeds, options, strict=True)]

    def render(self) -> list[Any]:
        return [env.render() for env in self.envs]

    def get_attr(self, name: str, local: Sequence[int]) -> list[Any]:
        return [self.envs[i].get_wrapper_attr(name) for i in local]

    def has_attr(self, name: str) -> bool:
        try:
            for env in self.envs:
                env.get_wrapper_attr(name)
        except AttributeError:
            return False
        return True

    def set_attr(self, name: str, value: Any, local: Sequence[int]) -> list[None]:
        for i in local:
            setattr(self.envs[i], name, value)
        return [None] * len(local)

    def env_method(self, name: str, args: tuple[Any, ...], kwargs: dict[str, Any], local: Sequence[int]) -> list[Any]:
        return [self.envs[i].get_wrapper_attr(name)(*args, **kwargs) for i in local]

    def is_wrapped(self, wrapper_class: type[gym.Wrapper], local: Sequence[int]) -> list[bool]:
        return [is_wrapped(self.envs[i], wrapper_class) for i in local]

    def close(self) -> None:
        for env in self.envs:
            env.close()


def plan_workers(n_envs: int, envs_per_worker: int | None, cpus: float, cpus_per_worker: float = 1.0) -> list[list[int]]:
    """Contiguous groups of env indices, one per Ray actor; ``None``: as few envs per actor as the CPUs allow.

    More actors than the cluster has CPUs for would wait forever to be scheduled: that is an error.
    """
    if n_envs < 1 or (envs_per_worker is not None and envs_per_worker < 1) or cpus_per_worker <= 0:
        raise ValueError(f"need n_envs >= 1, envs_per_worker >= 1 and cpus_per_worker > 0, got {n_envs}, {envs_per_worker}, "
                         f"{cpus_per_worker}")
    slots = int(cpus // cpus_per_worker)
    if envs_per_worker is None:
        envs_per_worker = -(-n_envs // max(1, slots))
    actors = -(-n_envs // envs_per_worker)
    if actors > slots:
        raise UnavailableError(
            f"{actors} Ray env workers of {cpus_per_worker:g} CPU need {actors * cpus_per_worker:g} CPUs, the cluster has "
            f"{cpus:g}: put more envs in each (envs_per_worker >= {-(-n_envs // max(1, slots))}) or add nodes")
    return [list(range(start, min(start + envs_per_worker, n_envs))) for start in range(0, n_envs, envs_per_worker)]


class RayVecEnv(VecEnv):
    """``SubprocVecEnv`` with Ray actors as the workers: ``envs_per_worker`` environments per actor
    (default: one per actor if the cluster has the CPUs, else as few as fit; see :func:`plan_workers`).

    Needs a connected Ray runtime (:func:`giwbc.distributed.connect`); each actor takes
    ``cpus_per_worker`` CPUs of the cluster, wherever Ray places it. ``transport``: how steps travel,
    ``"channel"`` (default) or ``"calls"`` (see the module's docstring).
    """

    def __init__(self, env_fns: list[Callable[[], gym.Env]], envs_per_worker: int | None = None, cpus_per_worker: float = 1.0,
                 transport: str = "channel") -> None:
        if transport not in TRANSPORTS:
            raise ValueError(f"transport must be one of {', '.join(TRANSPORTS)}, got {transport!r}")
        self._ray = ray = require_ray()
        if not ray.is_initialized():
            raise UnavailableError("RayVecEnv needs a Ray runtime: call giwbc.distributed.connect() first")
        self.closed, self.waiting = False, False
        n = len(env_fns)
        self.groups = plan_workers(n, envs_per_worker, float(ray.cluster_resources().get("CPU", 0.0)), cpus_per_worker)
        actor_class = ray.remote(num_cpus=cpus_per_worker, max_restarts=0, max_task_retries=0)(EnvWorker)
        self.workers = [actor_class.remote([env_fns[i] for i in group]) for group in self.groups]
        self._where = {env: (w, local) for w, group in enumerate(self.groups) for local, env in enumerate(group)}
        self._lost: str | None = None  # set once a worker died: every later call fails with it
        observation_space, action_space = self._get([self.workers[0].spaces.remote()], [0])[0]
        self._pending: Any = None
        self.transport = transport
        self._channels: list[Connection] = self._open_channels() if transport == "channel" else []
        super().__init__(n, observation_space, action_space)

    def _open_channels(self) -> list[Connection]:
        """One authenticated connection to each actor (a fresh key per vector env, sent through Ray)."""
        authkey = secrets.token_bytes(32)
        addresses = self._get([worker.open_channel.remote(authkey) for worker in self.workers], range(len(self.workers)))
        channels: list[Connection] = []
        try:
            for address in addresses:
                channels.append(Client(tuple(address), authkey=authkey))
        except OSError as error:  # a firewall between this machine and a node, most likely
            for channel in channels:
                channel.close()
            for worker in self.workers:
                self._ray.kill(worker)
            raise UnavailableError(
                f"cannot open a channel to the Ray env worker at {address[0]}:{address[1]} ({error}): let this machine reach "
                "the nodes' TCP ports, or step through Ray's own calls (RayVecEnv(transport='calls'))") from None
        return channels

    # --- the Ray calls, with a lost worker reported as such ----------------------------------------
    def _get(self, refs: list[Any], workers: Sequence[int]) -> list[Any]:
        """``ray.get(refs)``; a lost worker becomes a :class:`WorkerLostError`."""
        ray = self._ray
        if self._lost is not None:
            raise WorkerLostError(self._lost)
        try:
            return ray.get(refs)
        except system_failures(ray) as error:
            self._report_lost(error, workers)

    def _report_lost(self, error: BaseException, workers: Sequence[int]) -> NoReturn:
        """Name the workers of ``workers`` that no longer answer, remember it, raise :class:`WorkerLostError`."""
        ray = self._ray
        probes = {w: self.workers[w].ping.remote() for w in workers}  # a live actor answers at once
        lost = []
        for w, probe in probes.items():
            try:
                ray.get(probe, timeout=10.0)
            except (ray.exceptions.GetTimeoutError, *system_failures(ray)):
                lost.append(f"worker {w} (envs {self.groups[w][0]}..{self.groups[w][-1]})")
        reason = first_line(error) or "connection closed"
        self._lost = (f"Ray environment {', '.join(lost) or 'worker'} died ({type(error).__name__}: {reason}): "
                      "its environments' states are lost, the rollout cannot continue")
        raise WorkerLostError(self._lost) from None

    def _call(self, method: str, indices: VecEnvIndices, *args: Any) -> list[Any]:
        """``method(*args, local indices)`` on the workers holding ``indices``; results in ``indices`` order."""
        wanted = [self._where[i] for i in self._get_indices(indices)]
        grouped: dict[int, list[int]] = {}
        for w, local in wanted:
            grouped.setdefault(w, []).append(local)
        refs = [getattr(self.workers[w], method).remote(*args, local) for w, local in grouped.items()]
        answers = {(w, local): value for (w, locals_), chunk in zip(grouped.items(), self._get(refs, list(grouped)), strict=True)
                   for local, value in zip(locals_, chunk, strict=True)}
        return [answers[key] for key in wanted]

    # --- VecEnv ----------------------------------------------------------------------------------
    def step_async(self, actions: np.ndarray) -> None:
        if self._lost is not None:
            raise WorkerLostError(self._lost)
        chunks = [actions[group[0]:group[-1] + 1] for group in self.groups]  # groups are contiguous: one array each
        if self._channels:
            try:
                for channel, chunk in zip(self._channels, chunks, strict=True):
                    channel.send(chunk)
            except OSError as error:  # the other end is gone
                self._report_lost(error, range(len(self.workers)))
        else:
            self._pending = [worker.step.remote(chunk) for worker, chunk in zip(self.workers, chunks, strict=True)]
        self.waiting = True

    def step_wait(self) -> VecEnvStepReturn:
        pending, self._pending = self._pending, None
        self.waiting = False
        if self._channels:
            chunks = self._receive()
        else:
            chunks = self._get(pending, range(len(self.workers)))
        results = [item for chunk in chunks for item in chunk]
        observations, rewards, dones, infos, self.reset_infos = zip(*results, strict=True)
        return _stack_obs(observations, self.observation_space), np.stack(rewards), np.stack(dones), infos

    def _receive(self) -> list[Any]:
        """Every actor's step results, in worker order; an env's own exception is raised as it is."""
        replies = []
        try:
            for channel in self._channels:
                replies.append(channel.recv())
        except (EOFError, OSError) as error:  # the actor's process (or node) died mid-step
            self._report_lost(error, range(len(self.workers)))
        for ok, value in replies:
            if not ok:
                raise value
        return [value for _, value in replies]

    def reset(self) -> VecEnvObs:
        refs = [worker.reset.remote([self._seeds[i] for i in group], [self._options[i] for i in group])
                for worker, group in zip(self.workers, self.groups)]
        results = [item for chunk in self._get(refs, range(len(self.workers))) for item in chunk]
        observations, self.reset_infos = zip(*results, strict=True)
        self._reset_seeds()
        self._reset_options()
        return _stack_obs(observations, self.observation_space)

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        try:
            for channel in self._channels:
                channel.close()  # the actor's serving thread sees EOF and ends
            self._ray.get([worker.close.remote() for worker in self.workers])
        except system_failures(self._ray):
            pass  # a lost worker has nothing left to close
        finally:
            for worker in self.workers:
                self._ray.kill(worker)

    def get_images(self) -> Sequence[np.ndarray | None]:
        refs = [worker.render.remote() for worker in self.workers]
        return [image for chunk in self._get(refs, range(len(self.workers))) for image in chunk]

    def has_attr(self, attr_name: str) -> bool:
        refs = [worker.has_attr.remote(attr_name) for worker in self.workers]
        return all(self._get(refs, range(len(self.workers))))

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return self._call("get_attr", indices, attr_name)

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        self._call("set_attr", indices, attr_name, value)

    def env_method(self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **method_kwargs: Any) -> list[Any]:
        return self._call("env_method", indices, method_name, method_args, method_kwargs)

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None) -> list[bool]:
        return self._call("is_wrapped", indices, wrapper_class)
