"""BARN worlds before and after: the previous default filter's paths beside today's.

Usage: python bench/plot_barn_before_after.py [--worlds 19 55 151 250]
                                              [--out doc/images/barn_before_after.png]

Each world runs in lockstep (``barn_suite.run_world``) with both nominals (path and
go-to-goal), once with the filter the package shipped before the horizon barrier
(``polyc2bf_inflated``: eq. 7 on inflated polygons, the paper's midpoint axis, gamma 1,
no braking check, no deadlock resolution) and once with the shipped default
(``config/diff_drive.yaml``).  One column per world, one row per nominal; the outcome of
each run is printed.
"""
import argparse

from bench_io import require_installed_checkout

from sim_bridge.barn import load_worlds, WORLDS_FILE
from sim_bridge.evaluation.barn_suite import run_world
from sim_bridge.plots import barn_trajectories_figure

BEFORE = ('polyc2bf_inflated', {'filter.gamma': 1.0, 'filter.cone_axis': 'midpoint',
                                'filter.braking_check': False, 'deadlock_resolution': 'none'})
AFTER = ('polyc2bf_horizon', None)
NOMINALS = ('path', 'goal')


def main(argv=None):
    """Run the worlds before and after, print their outcomes and draw the figure."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--worlds', nargs='+', type=int, default=[19, 55, 151, 250])
    parser.add_argument('--out', default='doc/images/barn_before_after.png')
    args = parser.parse_args(argv)
    require_installed_checkout()
    worlds = {world.world: world for world in load_worlds(WORLDS_FILE)}
    chosen = [worlds[number] for number in args.worlds]
    trajectories, combos = {}, []
    for filter_name, parameters in (BEFORE, AFTER):
        for nominal in NOMINALS:
            combos.append((filter_name, nominal))
            for world in chosen:
                ((record, trajectory),) = run_world(world, [(filter_name, nominal)], parameters)
                trajectories[(world.world, filter_name, nominal)] = trajectory
                label = 'before' if parameters else 'after'
                print(f'world {world.world:>3} {nominal:<4} {label:<6} {record["outcome"]:<9} '
                      f'{record["time_s"]:6.1f} s', flush=True)
    barn_trajectories_figure(args.out, chosen, trajectories, combos)
    print(f'wrote {args.out}')


if __name__ == '__main__':
    main()
