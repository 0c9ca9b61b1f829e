"""Run every world of a suite x its combos over worker processes, with one progress bar.

Shared by the BARN and the dynamic suites (``barn_suite.run_barn``,
``dynamic_suite.run_dynamic``): ``run_world(world, combos, *arguments)`` returns one
``(record, trajectory)`` per combo, and worlds go out over ``jobs`` spawned processes (a
fresh interpreter per worker, whatever this process holds: PyBullet, DDS).
"""
import os
from concurrent.futures import as_completed, ProcessPoolExecutor
from multiprocessing import get_context

from sim_bridge.evaluation.progress import Progress


def run_worlds(worlds, combos, run_world, arguments=(), jobs=None, progress=True,
               label=lambda world: f'world {world.world}'):
    """Return (records, trajectories) of every world x combo, in world then combo order.

    ``jobs``: processes (default: the CPU count; one runs everything in this process);
    ``label(world)`` names a finished world on the progress bar (counted in runs).
    Trajectories are keyed by (world id, filter, nominal).
    """
    jobs = jobs or os.cpu_count() or 1
    bar = Progress(len(worlds) * len(combos)) if progress else None
    done, results = 0, {}

    def finished(world, result):
        nonlocal done
        results[world.world] = result
        done += len(combos)
        if bar is not None:
            bar.update(done, label(world), force=True)

    if jobs == 1:
        for world in worlds:
            finished(world, run_world(world, combos, *arguments))
    else:
        pool = ProcessPoolExecutor(min(jobs, len(worlds)), mp_context=get_context('spawn'))
        try:
            futures = {pool.submit(run_world, world, combos, *arguments): world
                       for world in worlds}
            for future in as_completed(futures):
                finished(futures[future], future.result())
        finally:
            pool.shutdown(cancel_futures=True)
    if bar is not None:
        bar.close()
    records, trajectories = [], {}
    for world in worlds:
        for record, trajectory in results[world.world]:
            records.append(record)
            trajectories[(record['world'], record['filter'], record['nominal'])] = trajectory
    return records, trajectories
