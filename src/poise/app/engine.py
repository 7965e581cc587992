"""The one engine of ``poise batch`` and ``poise sweep``: Dask distributed.

:func:`dask_client` gives a client: a ``LocalCluster`` of worker processes (one thread each, no
dashboard) by default, or an existing cluster by its scheduler address. :func:`run_tasks` runs
independent tasks on it and hands each result (or the exception it raised) back as it comes.
A cluster without a worker for ``worker_timeout`` seconds (a scheduler nobody joined, or whose
workers all died) ends the run with :class:`NoWorkers` (exit 2) after cancelling what had not
run; the caller keeps what finished. Under ``quiet`` no Dask log line or warning reaches stderr.
"""
from __future__ import annotations

import contextlib
import logging
import os
import signal
import threading
import time
import warnings

from poise.core.errors import UsageError
from poise.core.extras import require

#: default ``--worker-timeout``: seconds without any worker before a run gives up
WORKER_TIMEOUT = 120.0


class NoWorkers(UsageError):
    """No Dask worker for ``worker_timeout`` seconds (exit 2); ``rows``: what finished."""

    status = "no_workers"
    progress_end = "gave up"        # the last progress line says so (poise.core.progress)

    def __init__(self, message: str, rows=None):
        super().__init__(message)
        self.rows = rows


_DASK_LOGGERS = ("distributed", "dask", "tornado", "asyncio")


@contextlib.contextmanager
def _silenced():
    """Dask's loggers say nothing and warnings are dropped inside the block (every logger of
    those packages: Dask gives some children levels of their own, ``distributed.client``)."""
    names = [n for n in list(logging.root.manager.loggerDict)
             if n.split(".", 1)[0] in _DASK_LOGGERS]
    loggers = [logging.getLogger(n) for n in dict.fromkeys([*_DASK_LOGGERS, *names])]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.CRITICAL + 1)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yield
    finally:
        for lg, lv in zip(loggers, levels):
            lg.setLevel(lv)


@contextlib.contextmanager
def quiet_dask(quiet: bool):
    """Inside the block, under ``quiet``: Dask's loggers say nothing and warnings are dropped."""
    if not quiet:
        yield
        return
    with _silenced():
        yield


@contextlib.contextmanager
def _children_ignore_interrupt():
    """Processes started in the block ignore SIGINT from their first instruction on.

    Ctrl-C in a terminal signals the whole process group: a worker still starting Python
    would die with Python's own traceback. An ignored signal stays ignored across exec, so
    the workers never see it; the parent restores its handler after the block and stops them
    itself (a Ctrl-C during the block, the cluster's start-up, is not acted on).
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


#: seconds to reach a ``--scheduler`` and hear it say it is a Dask scheduler (at most)
CONNECT_TIMEOUT = 20.0


def check_scheduler(address: str) -> None:
    """A Dask scheduler address (``tcp://host:8786``, ``host:8786``) or a ``UsageError``."""
    where = f"--scheduler {address!r}"
    text = str(address).strip()
    try:
        from distributed.comm.addressing import parse_address, parse_host_port
        scheme, loc = parse_address(text if "://" in text else f"tcp://{text}", strict=False)
        if scheme in ("tcp", "tls"):
            host, port = parse_host_port(loc, default_port=8786)
            if not host or not 0 < int(port) < 65536:
                raise ValueError("no host or bad port")
    except Exception as e:  # noqa: BLE001 - whatever the parser says, the address is unusable
        raise UsageError(f"{where}: not a scheduler address (expected e.g. "
                         f"tcp://host:8786): {' '.join(str(e).split())}") from None


def probe_scheduler(address: str, timeout: float = CONNECT_TIMEOUT) -> None:
    """Ask ``address`` who it is (Dask's ``identity`` call) before a client connects to it.

    A port that does not answer within ``timeout`` seconds (a Dask client would wait forever
    for its handshake), answers bytes that are not Dask's protocol, or answers as something
    other than a scheduler is a :class:`UsageError` (exit 2) naming the address. Runs in a
    thread of its own (its own event loop), bounded by ``timeout``."""
    import asyncio
    from distributed.comm import connect
    from distributed.security import Security

    async def ask():
        # the client's connection arguments (TLS from the Dask configuration, as Client uses)
        comm = await connect(address, timeout=timeout,
                             **Security().get_connection_args("client"))
        try:
            await comm.write({"op": "identity", "reply": True})
            return await comm.read()
        finally:
            comm.abort()

    out: dict = {}

    def run():
        try:
            out["reply"] = asyncio.run(asyncio.wait_for(ask(), timeout + 0.5))
        except BaseException as e:  # noqa: BLE001 - garbage may raise anything (MemoryError)
            out["error"] = e

    th = threading.Thread(target=run, name="poise-scheduler-probe", daemon=True)
    th.start()
    th.join(timeout + 5.0)
    where = f"--scheduler {address!r}"
    err = out.get("error")
    reply = out.get("reply")
    if th.is_alive() or isinstance(err, (TimeoutError, asyncio.TimeoutError)):
        raise UsageError(f"{where}: no answer from a Dask scheduler within {timeout:g} s")
    if isinstance(err, OSError):
        raise UsageError(f"{where}: cannot connect: {' '.join(str(err).split())}")
    if err is not None or not isinstance(reply, dict) or reply.get("type") != "Scheduler":
        what = (f"it answered as {reply.get('type')!r}" if isinstance(reply, dict)
                and reply.get("type") else "its answer is not Dask's protocol")
        raise UsageError(f"{where}: not a Dask scheduler ({what})")


@contextlib.contextmanager
def _quiet_shutdown():
    """Dask's loggers say nothing while a client and its cluster close: a comm closed under a
    heartbeat (``CommClosedError: Stream is closed``) is logged with a traceback on a loaded
    machine, and nothing about closing a finished run is worth a line; errors closing it are
    dropped (the run's outcome is known)."""
    try:
        with _silenced():
            yield
    except Exception:  # noqa: BLE001 - see above
        pass


@contextlib.contextmanager
def dask_client(scheduler: str | None = None, workers: int | None = None, n_tasks: int = 1,
                client=None, quiet: bool = False, feature: str = "poise sweep",
                allowed_failures: int | None = None,
                worker_timeout: float | None = WORKER_TIMEOUT):
    """A Dask client for the block (closed after it unless ``client`` was given).

    ``scheduler``: address of an existing scheduler (asked first whether it is one,
    :func:`probe_scheduler`, within CONNECT_TIMEOUT or ``worker_timeout`` seconds); else a LocalCluster of
    ``workers`` processes (default: CPUs, at most ``n_tasks``) with no dashboard, its
    scheduler's HTTP endpoint on a free local port (never a "port 8787 is in use" warning),
    workers that log nothing. ``allowed_failures``: how often a task may be on a worker that
    dies before it fails with ``KilledWorker`` (local cluster only).
    """
    if client is not None:
        with quiet_dask(quiet):
            yield client
        return
    require("sweep", feature)
    import dask
    from dask.distributed import Client, LocalCluster
    cluster = None
    with quiet_dask(quiet):
        if scheduler:
            connect_timeout = min(CONNECT_TIMEOUT, worker_timeout or CONNECT_TIMEOUT)
            probe_scheduler(scheduler, connect_timeout)
            try:
                client = Client(scheduler, timeout=f"{connect_timeout:g}s")
            except (OSError, TimeoutError, ValueError, TypeError) as e:
                raise UsageError(f"--scheduler {scheduler!r}: cannot connect: {e}") from None
        else:
            # no statistical profiler in the workers: its history (an hour of stack samples)
            # is the memory a long sweep's workers would otherwise grow by
            cfg = {"distributed.worker.profile.enabled": False}
            if allowed_failures is not None:
                cfg["distributed.scheduler.allowed-failures"] = int(allowed_failures)
            nw = workers or os.cpu_count() or 1
            with dask.config.set(cfg), _children_ignore_interrupt():
                cluster = LocalCluster(n_workers=min(nw, max(1, n_tasks)), threads_per_worker=1,
                                       processes=True, dashboard_address=None,
                                       scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
                                       silence_logs=logging.CRITICAL)
            client = Client(cluster)
        try:
            yield client
        finally:
            with _quiet_shutdown():
                client.close()
            if cluster is not None:
                with _quiet_shutdown():
                    cluster.close()


def _n_workers(client) -> int:
    try:
        return len(client.nthreads())
    except Exception:  # noqa: BLE001 - scheduler gone: no workers
        return 0


def run_tasks(client, tasks: dict, on_done, worker_timeout: float | None = WORKER_TIMEOUT,
              what: str = "tasks", poll: float = 1.0, say=None) -> None:
    """Run ``tasks`` (``{key: (fn, *args)}``) on ``client``; ``on_done(key, value, exc)`` as each
    ends (``exc``: the exception it raised, e.g. ``KilledWorker``). Raises :class:`NoWorkers`
    when the cluster has no worker for ``worker_timeout`` seconds (None: wait forever).
    ``say(line)``: told once each time the cluster is found without a worker
    (``waiting for Dask workers at ADDRESS (up to N s)``)."""
    from dask.distributed import wait
    futs = {}
    for key, (fn, *args) in tasks.items():
        futs[client.submit(fn, *args, key=f"poise-{what}-{key}-{time.monotonic_ns()}",
                           pure=False)] = key
    pending = set(futs)
    total = len(futs)
    seen = time.monotonic()
    where = getattr(client.scheduler, "address", None) or "the scheduler"
    waiting = False
    try:
        while pending:
            try:
                done, pending = wait(pending, timeout=poll, return_when="FIRST_COMPLETED")
            except TimeoutError:            # nothing finished within ``poll``
                done = set()
            for f in done:
                try:
                    value, exc = f.result(), None
                except Exception as e:  # noqa: BLE001 - the task's or the cluster's error
                    value, exc = None, e
                on_done(futs.pop(f), value, exc)     # released: the cluster forgets it
                del value
            now = time.monotonic()
            if done or _n_workers(client):
                seen = now
                waiting = False
                continue
            if not waiting:             # said once each time the cluster is found empty
                waiting = True
                if say is not None:
                    limit = "" if worker_timeout is None else f" (up to {worker_timeout:g} s)"
                    say(f"waiting for Dask workers at {where}{limit}")
            if worker_timeout is not None and now - seen > worker_timeout:
                n = len(pending)
                raise NoWorkers(
                    f"no Dask worker at {where} for {worker_timeout:g} s (none joined, or all "
                    f"died): gave up with {n} of {total} {what} not run; what finished is "
                    f"kept (run again to do the rest; --worker-timeout to wait longer)")
    finally:
        if pending:
            client.cancel(list(pending))
