"""Sweeps: many run specs, in parallel processes or on a Dask cluster.

A sweep is a list of run specs (:mod:`catgraph.experiment`; usually from an
experiment configuration, :mod:`catgraph.config`). Each run is a pure function of its
spec, so the runs are independent and can execute anywhere in any order; only the
*results* are put back in spec order. :func:`run_sweep` chooses where:

* ``scheduler=None`` (default): on this machine, one run per worker process
  (``concurrent.futures.ProcessPoolExecutor`` with ``spawn``ed workers, so no thread
  or lock state of the caller is inherited), ``processes`` of them (default: the number
  of CPUs, at most the number of runs); ``processes=1`` runs serially in this process,
  which is the easiest to debug.
* ``scheduler="tcp://host:8786"``: on the Dask cluster of that scheduler
  (``dask.distributed``, an optional dependency: ``pip install "catgraph[dask]"``),
  with a client opened and closed here.
* ``scheduler=client``: on an existing ``distributed.Client`` (e.g. of a
  ``LocalCluster``), which is left open.

Because the runs are pure, the three give identical payloads, except for the
measured ``seconds``. Workers on a cluster must see the data at the same paths as the
configuration names (absolute paths after :func:`catgraph.config.load_config`).

Errors
------
``errors="raise"`` (default) stops at the first failing run and raises its error with
the run's name in the message (the other runs are cancelled). ``errors="record"`` keeps
going and puts ``{"name", "error", "spec"}`` in place of the failed run's payload, so a
long sweep loses only what failed.
"""

from __future__ import annotations

import os
import traceback
from collections.abc import Callable, Sequence
from typing import Any

from .exceptions import CatgraphError, InvalidParameterError, MissingDependencyError

__all__ = ["run_sweep", "MissingDependencyError"]


def _run_experiment(spec: dict) -> dict:
    from .experiment import run_experiment

    return run_experiment(spec)


def _guarded(runner: Callable[[dict], dict], spec: dict, record: bool) -> dict:
    """Run one spec; with ``record``, turn an exception into an error entry."""
    if not record:
        return runner(spec)
    try:
        return runner(spec)
    except Exception as exc:  # noqa: BLE001 - recorded for the report, the sweep goes on
        detail = "" if isinstance(exc, CatgraphError) else "\n" + traceback.format_exc(limit=5)
        return {"name": spec.get("name"), "error": f"{type(exc).__name__}: {exc}{detail}".rstrip(), "spec": spec}


def _labelled(exc: BaseException, spec: dict, index: int) -> BaseException:
    """The same error with the run's name in front of its message, where that is safe."""
    label = spec.get("name") or f"#{index + 1}"
    if isinstance(exc, CatgraphError):
        try:
            return type(exc)(f"run {label!r}: {exc}")
        except TypeError:
            return exc
    return exc


def _progress(total: int, enabled: bool, desc: str):
    from tqdm.auto import tqdm

    return tqdm(total=total, disable=not enabled, desc=desc, unit="run", dynamic_ncols=True)


def _check(specs: Sequence[dict], processes: int | None, errors: str) -> list[dict]:
    specs = list(specs)
    for k, spec in enumerate(specs):
        if not isinstance(spec, dict):
            raise InvalidParameterError(f"run spec #{k + 1} must be a dict (see catgraph.experiment); "
                                        f"got {type(spec).__name__}.")
    if processes is not None and (not isinstance(processes, int) or isinstance(processes, bool) or processes < 1):
        raise InvalidParameterError(f"The 'processes' parameter of run_sweep must be an int ≥ 1 or None. "
                                    f"Got {processes!r} instead.")
    if errors not in ("raise", "record"):
        raise InvalidParameterError(f"The 'errors' parameter of run_sweep must be 'raise' or 'record'. "
                                    f"Got {errors!r} instead.")
    return specs


def run_sweep(
    specs: Sequence[dict[str, Any]],
    scheduler: Any = None,
    processes: int | None = None,
    progress: bool = True,
    errors: str = "raise",
    runner: Callable[[dict], dict] | None = None,
    on_result: Callable[[int, dict], None] | None = None,
) -> list[dict[str, Any]]:
    """Run every spec and return the payloads in spec order.

    Parameters
    ----------
    specs : sequence of dict
        Run specs for :func:`catgraph.experiment.run_experiment`.
    scheduler : str or distributed.Client, optional
        ``None``: local worker processes. A scheduler address (``"tcp://host:8786"``)
        or a ``distributed.Client``: run on that Dask cluster.
    processes : int, optional
        Local worker processes (default: CPUs, at most the number of runs); ``1`` runs
        serially in this process. Ignored with a scheduler.
    progress : bool
        Show a progress bar (tqdm) on stderr.
    errors : {"raise", "record"}
        Stop at the first failure, or record failures as ``{"name", "error", "spec"}``.
    runner : callable, optional
        ``runner(spec) -> payload``; default :func:`~catgraph.experiment.run_experiment`.
        Must be importable by the workers (a module-level function).
    on_result : callable, optional
        ``on_result(k, payload)``, called in this process as run ``k`` finishes (its
        payload, or its error entry with ``errors="record"``): a caller can keep each
        result as it comes, so that an interrupted sweep loses only the runs not yet done.
        With ``errors="record"`` a run whose worker dies (a process killed, out of memory)
        is recorded as failed, and the others go on.

    Returns
    -------
    list of dict
        One payload per spec, in the order of ``specs``.

    Raises
    ------
    MissingDependencyError
        A scheduler is given but ``dask.distributed`` is not installed.
    CatgraphError
        With ``errors="raise"``: the first run's error, its message prefixed with the run
        name.
    """
    specs = _check(specs, processes, errors)
    runner = _run_experiment if runner is None else runner
    record = errors == "record"
    if not specs:
        return []
    done = on_result if on_result is not None else (lambda k, payload: None)
    if scheduler is not None:
        return _run_dask(specs, scheduler, progress, record, runner, done)
    n_workers = min(len(specs), processes or os.cpu_count() or 1)
    if n_workers == 1:
        return _run_serial(specs, progress, record, runner, done)
    return _run_processes(specs, n_workers, progress, record, runner, done)


def _lost(spec: dict, exc: BaseException) -> dict:
    """The error entry of a run whose worker failed it (not the run itself: a process
    killed, out of memory, a lost connection)."""
    return {"name": spec.get("name"), "spec": spec,
            "error": f"{type(exc).__name__}: the worker running it failed ({exc or 'no message'}); a process killed "
                     "or out of memory is the usual cause."}


def _run_serial(specs: list[dict], progress: bool, record: bool, runner, done) -> list[dict]:
    out = []
    with _progress(len(specs), progress, "sweep") as bar:
        for k, spec in enumerate(specs):
            try:
                out.append(_guarded(runner, spec, record))
            except CatgraphError as exc:
                raise _labelled(exc, spec, k) from exc
            done(k, out[-1])
            bar.update(1)
    return out


def _run_processes(specs: list[dict], n_workers: int, progress: bool, record: bool, runner, done) -> list[dict]:
    import multiprocessing
    from concurrent.futures import FIRST_EXCEPTION, ProcessPoolExecutor, wait

    results: list[dict | None] = [None] * len(specs)
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=n_workers, mp_context=context) as pool, \
            _progress(len(specs), progress, f"sweep ({n_workers} processes)") as bar:
        futures = {pool.submit(_guarded, runner, spec, record): k for k, spec in enumerate(specs)}
        pending = set(futures)
        try:
            while pending:
                finished, pending = wait(pending, return_when=FIRST_EXCEPTION)
                for future in finished:
                    k = futures[future]
                    exc = future.exception()
                    if exc is not None and not record:
                        raise _labelled(exc, specs[k], k) from exc
                    results[k] = future.result() if exc is None else _lost(specs[k], exc)
                    done(k, results[k])
                    bar.update(1)
        except BaseException:
            for future in pending:
                future.cancel()
            pool.shutdown(wait=True, cancel_futures=True)
            raise
    return results  # type: ignore[return-value]


def connect(address: str):
    """A ``distributed.Client`` connected to the scheduler at ``address``.

    Raises
    ------
    MissingDependencyError
        dask.distributed is not installed.
    CatgraphError
        The address is malformed, or no scheduler answers there within 20 s.
    """
    try:
        from distributed import Client
    except ImportError:
        raise MissingDependencyError(
            'running on Dask needs dask.distributed, an optional dependency: pip install "catgraph[dask]"'
        ) from None
    try:
        return Client(address, timeout="20s")
    except (OSError, TimeoutError, ValueError, TypeError) as exc:
        raise CatgraphError(f"cannot connect to the Dask scheduler at {address!r} ({exc}); give its address as "
                            "tcp://HOST:PORT (e.g. tcp://127.0.0.1:8786) and check that the scheduler is "
                            "running.") from None


def _dask_client(scheduler: Any):
    """(client, owned): a client for ``scheduler`` and whether this module must close it."""
    if isinstance(scheduler, str):
        return connect(scheduler), True
    if not (hasattr(scheduler, "submit") and hasattr(scheduler, "gather")):
        raise InvalidParameterError(f"The 'scheduler' parameter of run_sweep must be None, a scheduler address "
                                    f"such as 'tcp://host:8786', or a distributed.Client. Got {scheduler!r} instead.")
    return scheduler, False


def _run_dask(specs: list[dict], scheduler: Any, progress: bool, record: bool, runner, done) -> list[dict]:
    client, owned = _dask_client(scheduler)
    from distributed import as_completed

    try:
        futures = [client.submit(_guarded, runner, spec, record, pure=False, key=f"catgraph-run-{k}-{os.urandom(4).hex()}")
                   for k, spec in enumerate(specs)]
        index = {future.key: k for k, future in enumerate(futures)}
        results: list[dict | None] = [None] * len(specs)
        with _progress(len(specs), progress, "sweep (dask)") as bar:
            try:
                for future in as_completed(futures):
                    k = index[future.key]
                    try:
                        results[k] = future.result()
                    except CatgraphError as exc:
                        raise _labelled(exc, specs[k], k) from exc
                    except Exception as exc:  # noqa: BLE001 - a worker lost (killed, out of memory)
                        if not record:
                            raise
                        results[k] = _lost(specs[k], exc)
                    done(k, results[k])
                    bar.update(1)
            except BaseException:
                client.cancel(futures)
                raise
        return results  # type: ignore[return-value]
    finally:
        if owned:
            client.close()
