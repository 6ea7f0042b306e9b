"""Worker processes on a Ray cluster: ``backend=ray`` of ``vla-gr eval`` and ``vla-gr collect``.

:func:`map_on_ray` is :func:`vla_gr.data.collect.map_in_workers` with Ray actors as the worker
processes: each actor runs ``init(*init_args)`` once, then ``work(item)`` for each item it is
handed, so an episode runs the very code a local worker runs. Items go one at a time to
whichever actor is free; results are yielded in the order of ``items`` as soon as they can be
(one that finishes early waits in a buffer), so the one process that writes them (the driver)
writes what the local backend writes, and a killed run resumes from its file as a local one.

Everything a worker needs travels through Ray's object store, not a shared filesystem: the
init arguments are put there once (a checkpoint as the bytes of its files, see
:mod:`vla_gr.evaluation.ray_rows`), an episodes file as its specs (:func:`portable_env_kwargs`).
Rendering and offline settings of this process (:data:`FORWARDED_ENV`) are set on the workers,
so that they render the same pixels. A worker that dies ends the run (run it again: it resumes).

``ray`` is an optional extra (``pip install 'vla-gr[ray]'``), imported here only, lazily.
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

from vla_gr.errors import ConfigError

log = logging.getLogger(__name__)

#: Environment variables of this process that workers get too (rendering, offline hubs).
FORWARDED_ENV = ("MUJOCO_GL", "PYOPENGL_PLATFORM", "HF_HUB_OFFLINE", "TRANSFORMERS_OFFLINE")
#: Seconds a cluster's address gets to answer before the run is refused.
CONNECT_TIMEOUT_S = 5.0
#: Seconds the workers get to close their envs (and remove their files) at the end.
CLOSE_TIMEOUT_S = 30.0


def import_ray(section: str = "eval"):
    """The ``ray`` module; a one-line ConfigError naming ``<section>.backend`` when it is not
    installed."""
    from vla_gr.configs.schema import check_backend

    try:
        check_backend(f"{section}.backend", "ray")
    except ValueError as err:
        raise ConfigError(str(err)) from None
    import ray

    return ray


@contextlib.contextmanager
def ray_connection(address: str | None, cpus: int, section: str = "eval") -> Iterator:
    """``ray`` connected to the cluster at ``address`` (None: a new local one of ``cpus``
    CPUs); disconnected after, unless this process was connected before. Errors name
    ``<section>.ray_address``."""
    ray = import_ray(section)
    if ray.is_initialized():
        yield ray
        return
    quiet = {"log_to_driver": False, "logging_level": logging.WARNING}
    if address is None:
        ray.init(address="local", num_cpus=cpus, include_dashboard=False, **quiet)
    else:
        where = f"{section}.ray_address={address}"
        _check_reachable(address, where)
        try:
            ray.init(address=address, **quiet)
        except (ConnectionError, ValueError, RuntimeError) as err:
            first = (str(err).strip() or type(err).__name__).splitlines()[0]
            raise ConfigError(f"{where}: no Ray cluster there ({first})") from None
    try:
        yield ray
    finally:
        ray.shutdown()


def _check_reachable(address: str, where: str) -> None:
    """ConfigError at once when ``address`` is ``host:port`` and nothing listens there (Ray
    itself would retry for minutes); other forms (``auto``, ``ray://...``) are left to Ray."""
    host, sep, port = address.rpartition(":")
    if not sep or not host or not port.isdigit() or "/" in address:
        return
    try:
        socket.create_connection((host, int(port)), timeout=CONNECT_TIMEOUT_S).close()
    except OSError as err:
        raise ConfigError(f"{where}: no Ray cluster answers there ({err})") from None


class _Worker:
    """A Ray actor: ``init(*init_args)`` once, then ``work(item)`` per :meth:`run`."""

    def __init__(self, init: Callable, work: Callable, close: Callable, *init_args) -> None:
        self._work, self._close = work, close
        init(*init_args)

    def run(self, item):
        return self._work(item)

    def close(self) -> None:
        self._close()


def map_on_ray(
    init: Callable,
    init_args: tuple,
    work: Callable,
    items: Sequence,
    workers: int,
    close: Callable,
    address: str | None = None,
    section: str = "eval",
    gpus: float = 0.0,
) -> Iterator:
    """``work(item)`` for each of ``items``, yielded in that order, from ``workers`` Ray actors
    (fewer when the cluster cannot hold them all at once) on the cluster at ``address`` (None:
    a local cluster started for this call).

    Each actor holds one CPU (and ``gpus`` GPUs: Ray sets its ``CUDA_VISIBLE_DEVICES``), runs
    ``init(*init_args)`` once (its env, its agent) and ``close()`` at the end;
    ``init``, ``work`` and ``close`` must be module-level functions (Ray pickles them by
    name). ``section`` names the config section in errors (``eval``, ``collect``).
    """
    if workers < 1:
        raise ValueError(f"workers={workers} must be >= 1")
    if not items:
        return
    with ray_connection(address, min(workers, len(items)), section) as ray:
        n = _workers_that_fit(ray.cluster_resources(), min(workers, len(items)), gpus, section)
        env_vars = {k: os.environ[k] for k in FORWARDED_ENV if k in os.environ}
        actor_class = ray.remote(num_cpus=1, num_gpus=gpus)(_Worker)
        options = {"runtime_env": {"env_vars": env_vars}} if env_vars else {}
        refs = [ray.put(arg) for arg in init_args]  # once in the object store, for every actor
        actors = [actor_class.options(**options).remote(init, work, close, *refs) for _ in range(n)]
        try:
            yield from _in_order(ray, actors, items)
        finally:
            _stop(ray, actors)


def _workers_that_fit(total: dict, wanted: int, gpus: float, section: str) -> int:
    """How many of ``wanted`` workers (one CPU and ``gpus`` GPUs each) the cluster's
    resources ``total`` hold at once: an actor that cannot be placed would hold up the
    episodes handed to it, so there are never more."""
    need = {"CPU": 1.0, **({"GPU": gpus} if gpus > 0 else {})}
    fits = min(int(total.get(key, 0) // amount) for key, amount in need.items())
    if fits < 1:
        have = ", ".join(f"{total.get(k, 0):g} {k}" for k in need)
        raise ConfigError(
            f"{section}.backend=ray: the Ray cluster has {have}, a worker needs "
            f"{', '.join(f'{v:g} {k}' for k, v in need.items())}"
        )
    if fits < wanted:
        log.warning("the Ray cluster holds %d workers at once, not %d", fits, wanted)
    return min(fits, wanted)


def _in_order(ray, actors: list, items: Sequence) -> Iterator:
    """Results of ``items`` handed one at a time to whichever actor is free, in item order."""
    queue = iter(enumerate(items))
    pending: dict = {}  # ref -> (position, actor)
    done: dict[int, object] = {}  # results that came back before an earlier item's
    following = 0

    def hand(actor) -> None:
        nxt = next(queue, None)
        if nxt is not None:
            pending[actor.run.remote(nxt[1])] = (nxt[0], actor)

    for actor in actors:
        hand(actor)
    while pending:
        ready, _ = ray.wait(list(pending), num_returns=1)
        for ref in ready:
            position, actor = pending.pop(ref)
            done[position] = ray.get(ref)
            hand(actor)
        while following in done:
            yield done.pop(following)
            following += 1


def _stop(ray, actors: list) -> None:
    """Close every actor (its env, its files), then end it."""
    try:
        ray.get([a.close.remote() for a in actors], timeout=CLOSE_TIMEOUT_S)
    except Exception as err:  # noqa: BLE001 - a dead or stuck actor is ended below anyway
        log.debug("closing the Ray workers: %s", err)
    for actor in actors:
        ray.kill(actor, no_restart=True)


def portable_env_kwargs(env_kwargs: dict) -> dict:
    """``env_kwargs`` whose ``episodes`` file (a path on this machine) is replaced by the
    episode specs it holds (the env takes either), so that a worker elsewhere needs no file."""
    from vla_gr.envs.episodes import load_episodes

    episodes = env_kwargs.get("episodes")
    if not isinstance(episodes, str | Path):
        return dict(env_kwargs)
    # check=False: the driver checked the file against its houses when it planned the episodes
    return {**env_kwargs, "episodes": load_episodes(episodes, check=False)}
