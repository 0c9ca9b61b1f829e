"""Trajectory and metrics plots of closed-loop runs (matplotlib, no display needed).

Figures are built with ``matplotlib.figure.Figure`` (no pyplot state, no GUI
backend) and written as PNG.  Top views draw, as the paper's figures do:

- obstacles as filled polygons at t = 0 (grey static, orange moving: dashed
  outline where it is at the end of the run and an arrow of its travel;
  pop-ups hatched with their appearance time);
- C3BF's virtual obstacle for each obstacle: its minimum enclosing circle
  grown by the robot radius, red dotted (paper Fig. 1 and sec. VI);
- each robot's start (circle), goal (star) and path, and a cross where a
  collision was first detected.

Quadrotor scenarios add a side view (x, z) with each prism's x extent and z range.

BARN figures (``barn_*``): outcome shares per filter x nominal beside the DWA
baseline, sample worlds' cylinders with each filter's path, and the metric's
histogram.  Dynamic-world figures (``dynamic_*``): outcome shares per difficulty, and
sample worlds' cylinder loops, the cylinders where a run ended and each filter's path.
"""
import math

import numpy as np
from matplotlib.collections import PatchCollection
from matplotlib.figure import Figure
from matplotlib.patches import Circle, FancyArrowPatch, Polygon, Rectangle

from polyc2bf_ros.core.geometry.polygons import minimum_enclosing_circle
from sim_bridge.dynamic_worlds import COURSE, CYLINDER_RADIUS, GOAL, START
from sim_bridge.robots import ROBOT_TYPES
from sim_bridge.world import CLEARANCE_RANGE

C3BF_STYLE = {'fill': False, 'edgecolor': 'tab:red', 'linestyle': ':', 'linewidth': 1.2}
FILTER_COLORS = {'polyc2bf_paper': 'tab:blue', 'polyc2bf_inflated': 'tab:green',
                 'c3bf': 'tab:red', 'polyc2bf_horizon': 'tab:orange', 'none': 'black'}
ROBOT_COLORS = ('tab:blue', 'tab:purple', 'tab:olive', 'tab:cyan', 'tab:brown', 'tab:pink')
# The view spans the paths, starts and goals, grown to include obstacles and circles
# but by at most this much [m] (a 60 m wall would shrink the paths to nothing).
VIEW_REACH = 10.0
MARGIN = 1.0


def is_aerial(scenario):
    """Return True when some robot of the scenario flies (a side view is useful)."""
    return any(ROBOT_TYPES[robot.type].aerial for robot in scenario.robots)


def c3bf_circles(scenario, robot_radius):
    """Return ``[(centre (2,), radius)]``: each obstacle's enclosing circle + robot radius."""
    circles = []
    for obstacle in scenario.all_obstacles():
        centre, radius = minimum_enclosing_circle(obstacle.polygon)
        circles.append((centre, radius + robot_radius))
    return circles


def _bounds(points):
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    return points.min(axis=0), points.max(axis=0)


def _view(scenario, paths, circles):
    """Return (lower, upper) corners of the top view."""
    core = [np.asarray(p)[:, :2] for p in paths]
    core += [r.position[:2] for r in scenario.robots] + [r.goal[:2] for r in scenario.robots]
    low, high = _bounds(np.vstack(core))
    extra = [o.polygon for o in scenario.all_obstacles()]
    extra += [np.array([c - r, c + r]) for c, r in circles]
    if extra:
        e_low, e_high = _bounds(np.vstack(extra))
        low = np.maximum(np.minimum(low, e_low), low - VIEW_REACH)
        high = np.minimum(np.maximum(high, e_high), high + VIEW_REACH)
    return low - MARGIN, high + MARGIN


def draw_top(ax, scenario, paths, robot_radius, labels=None, colors=None, collisions=(),
             end_time=None):
    """Draw the top view of ``scenario`` with ``paths`` [(K, >= 2) positions] on ``ax``.

    ``labels``/``colors`` per path; ``collisions`` are (x, y) points marked with a
    cross; ``end_time`` [s] places moving obstacles' final outlines (default: duration).
    """
    end_time = scenario.duration if end_time is None else end_time
    circles = c3bf_circles(scenario, robot_radius)
    for obstacle in scenario.all_obstacles():
        moving = obstacle.moving
        style = {'facecolor': 'tab:orange' if moving else '0.55', 'edgecolor': '0.2',
                 'alpha': 0.8, 'linewidth': 0.8}
        if obstacle.appear_at > 0.0:
            style.update(hatch='///', facecolor='0.85')
        ax.add_patch(Polygon(obstacle.polygon, closed=True, **style))
        if obstacle.appear_at > 0.0:
            x, y = obstacle.polygon.mean(axis=0)
            ax.annotate(f'appears at {obstacle.appear_at:g} s', (x, y), fontsize=7,
                        ha='center', va='bottom', xytext=(0, 12), textcoords='offset points')
        if moving:
            shift = obstacle.velocity * max(end_time - obstacle.appear_at, 0.0)
            ax.add_patch(Polygon(obstacle.polygon + shift, closed=True, fill=False,
                                 edgecolor='tab:orange', linestyle='--', linewidth=0.8))
            centre = obstacle.polygon.mean(axis=0)
            ax.add_patch(FancyArrowPatch(centre, centre + shift, arrowstyle='->',
                                         mutation_scale=8, color='tab:orange'))
    for index, (centre, radius) in enumerate(circles):
        ax.add_patch(Circle(centre, radius, label='C3BF virtual obstacle' if index == 0 else None,
                            **C3BF_STYLE))
    for index, path in enumerate(paths):
        path = np.asarray(path)
        color = colors[index] if colors else ROBOT_COLORS[index % len(ROBOT_COLORS)]
        label = labels[index] if labels else None
        ax.plot(path[:, 0], path[:, 1], color=color, linewidth=1.4, label=label)
    for index, robot in enumerate(scenario.robots):
        color = ROBOT_COLORS[index % len(ROBOT_COLORS)] if not colors else 'black'
        ax.plot(*robot.position[:2], 'o', color=color, markersize=5,
                label='start' if index == 0 else None)
        ax.plot(*robot.goal[:2], '*', color=color, markersize=10,
                label='goal' if index == 0 else None)
    for index, point in enumerate(collisions):
        ax.plot(*point[:2], 'x', color='red', markersize=9, markeredgewidth=2,
                label='collision' if index == 0 else None)
    low, high = _view(scenario, paths, circles)
    ax.set_xlim(low[0], high[0])
    ax.set_ylim(low[1], high[1])
    ax.set_aspect('equal')
    ax.set_xlabel('x [m]')
    ax.set_ylabel('y [m]')
    ax.grid(True, linewidth=0.3)


def draw_side(ax, scenario, paths, labels=None, colors=None):
    """Draw the side view (x, z): each prism's x extent over its z range, paths' x and z."""
    for obstacle in scenario.all_obstacles():
        x_low, x_high = obstacle.polygon[:, 0].min(), obstacle.polygon[:, 0].max()
        ax.add_patch(Rectangle((x_low, obstacle.z[0]), x_high - x_low,
                               obstacle.z[1] - obstacle.z[0], facecolor='0.55',
                               edgecolor='0.2', alpha=0.6))
    for index, path in enumerate(paths):
        path = np.asarray(path)
        color = colors[index] if colors else ROBOT_COLORS[index % len(ROBOT_COLORS)]
        ax.plot(path[:, 0], path[:, 2], color=color, linewidth=1.4,
                label=labels[index] if labels else None)
    for robot in scenario.robots:
        ax.plot(robot.position[0], robot.position[2], 'ok', markersize=5)
        ax.plot(robot.goal[0], robot.goal[2], '*k', markersize=10)
    ax.set_xlabel('x [m]')
    ax.set_ylabel('z [m]')
    ax.set_ylim(bottom=0.0)
    ax.grid(True, linewidth=0.3)


def trajectory_figure(path_png, scenario, paths, robot_radius, title, labels=None,
                      collisions=()):
    """Write the trajectory PNG of one run: top view, plus a side view for aerial robots."""
    aerial = is_aerial(scenario)
    low, high = _view(scenario, paths, c3bf_circles(scenario, robot_radius))
    height = min(max(6.5 * (high[1] - low[1]) / (high[0] - low[0]) + 1.2, 3.5), 8.0)
    figure = Figure(figsize=(12.0, max(height, 5.0)) if aerial else (7.5, height),
                    layout='constrained')
    axes = figure.subplots(1, 2 if aerial else 1, squeeze=False)[0]
    draw_top(axes[0], scenario, paths, robot_radius, labels=labels, collisions=collisions)
    axes[0].set_title('top view')
    if aerial:
        draw_side(axes[1], scenario, paths, labels=labels)
        axes[1].set_title('side view')
    axes[0].legend(loc='best', fontsize=8)
    figure.suptitle(title)
    figure.savefig(path_png, dpi=110)


def grid_figure(path_png, panels, robot_radius, title):
    """Write a grid of top views: ``panels`` is [(scenario, {filter: [paths]}, collisions)]."""
    columns = min(3, len(panels))
    rows = math.ceil(len(panels) / columns)
    figure = Figure(figsize=(5.0 * columns, 4.8 * rows), layout='constrained')
    axes = figure.subplots(rows, columns, squeeze=False).ravel()
    for ax, (scenario, by_filter, collisions) in zip(axes, panels):
        paths, labels, colors = [], [], []
        # Unfiltered paths first, so that the filters' paths are drawn over them.
        for name, robot_paths in sorted(by_filter.items(), key=lambda item: item[0] != 'none'):
            for index, path in enumerate(robot_paths):
                paths.append(path)
                labels.append(name if index == 0 else None)
                colors.append(FILTER_COLORS.get(name, 'gray'))
        draw_top(ax, scenario, paths, robot_radius(scenario), labels=labels, colors=colors,
                 collisions=collisions)
        ax.set_title(scenario.name)
    for ax in axes[len(panels):]:
        ax.set_visible(False)
    axes[0].legend(loc='best', fontsize=7)
    figure.suptitle(title)
    figure.savefig(path_png, dpi=90)


def metrics_figure(path_png, rows, filters, scenarios):
    """Bar charts per scenario and filter: success rate, min clearance, time ratio, fallback.

    ``rows`` are aggregated table rows with keys scenario, filter, success_rate,
    min_clearance_m, time_to_goal_ratio, fallback_rate (None where undefined).
    """
    panels = (('success_rate', 'success rate'),
              ('min_clearance_m', f'min clearance [m]\n(capped at {CLEARANCE_RANGE:g})'),
              ('time_to_goal_ratio', 'time to goal /\nobstacle-free\n(none: not reached)'),
              ('fallback_rate', 'fallback rate'))
    lookup = {(r['scenario'], r['filter']): r for r in rows}
    figure = Figure(figsize=(max(8.0, 1.1 * len(scenarios) + 3.0), 11.0), layout='constrained')
    axes = figure.subplots(len(panels), 1, sharex=True)
    width = 0.8 / max(1, len(filters))
    x = np.arange(len(scenarios))
    for ax, (key, label) in zip(axes, panels):
        for index, name in enumerate(filters):
            values = [lookup.get((s, name), {}).get(key) for s in scenarios]
            if key == 'min_clearance_m':  # None: nothing came within the clearance range
                values = [CLEARANCE_RANGE if (s, name) in lookup and v is None else v
                          for s, v in zip(scenarios, values)]
            heights = [np.nan if v is None else v for v in values]
            ax.bar(x + (index - 0.5 * (len(filters) - 1)) * width, heights, width,
                   label=name, color=FILTER_COLORS.get(name, 'gray'))
        ax.set_ylabel(label)
        ax.grid(True, axis='y', linewidth=0.3)
        ax.axhline(0.0, color='black', linewidth=0.6)
    axes[-1].set_xticks(x, scenarios, rotation=30, ha='right')
    figure.legend(*axes[0].get_legend_handles_labels(), ncols=len(filters), fontsize=9,
                  loc='outside upper center')
    figure.savefig(path_png, dpi=90)


# -- BARN ----------------------------------------------------------------------------------

OUTCOME_COLORS = {'success': 'tab:green', 'collision': 'tab:red', 'deadlock': 'tab:orange',
                  'timeout': '0.6'}
NOMINAL_STYLES = {'path': '-', 'goal': '--'}


def _combo_label(name, nominal):
    return f'{name}\n{nominal}'


def barn_outcomes_figure(path_png, rows, baseline):
    """Stacked bars per filter x nominal: shares of success, collision, deadlock, timeout.

    ``rows`` are ``barn_suite.aggregate_barn`` rows; ``baseline`` (DWA) is the last bar.
    """
    labels = [_combo_label(r['filter'], r['nominal']) for r in rows] + ['DWA\n(BARN)']
    shares = {outcome: [r[outcome] for r in rows] + [baseline.get(outcome, 0.0)]
              for outcome in OUTCOME_COLORS}
    figure = Figure(figsize=(max(6.0, 1.1 * len(labels) + 1.5), 4.8), layout='constrained')
    ax = figure.subplots()
    x = np.arange(len(labels))
    bottom = np.zeros(len(labels))
    for outcome, color in OUTCOME_COLORS.items():
        ax.bar(x, shares[outcome], 0.7, bottom=bottom, color=color, label=outcome)
        bottom += shares[outcome]
    for index, share in enumerate(shares['success']):
        ax.annotate(f'{share:.2f}', (index, share / 2), ha='center', va='center', fontsize=8)
    ax.set_xticks(x, labels, fontsize=8)
    ax.set_ylim(0.0, 1.0)
    ax.set_ylabel('share of worlds')
    ax.grid(True, axis='y', linewidth=0.3)
    ax.legend(loc='upper center', bbox_to_anchor=(0.5, -0.15), ncols=4, fontsize=8)
    ax.set_title("BARN outcomes (DWA: the benchmark's published baseline)")
    figure.savefig(path_png, dpi=90)


def _draw_barn_world(ax, world):
    """Draw the cylinders, reference path, start and goal (with its 1 m circle) of a world."""
    ax.add_collection(PatchCollection([Circle(c, world.cylinder_radius) for c in world.centers],
                                      facecolor='0.45', edgecolor='none'))
    ax.plot(*world.reference_path.T, color='0.3', linestyle=':', linewidth=1.0,
            label='reference path')
    ax.plot(*world.start[:2], 'ok', markersize=4)
    ax.plot(*world.goal, '*k', markersize=9)
    ax.add_patch(Circle(world.goal, 1.0, fill=False, edgecolor='0.4', linewidth=0.6))
    low = np.minimum(world.centers.min(axis=0), world.goal - 1.0) - 0.3
    high = np.maximum(world.centers.max(axis=0), world.goal + 1.0) + 0.3
    ax.set_xlim(low[0], high[0])
    ax.set_ylim(low[1], high[1])
    ax.set_aspect('equal')
    ax.tick_params(labelsize=7)


def barn_trajectories_figure(path_png, worlds, trajectories, combos):
    """Grid of sample worlds (columns) x nominal (rows), every filter's path over the cylinders.

    ``trajectories[(world id, filter, nominal)]`` holds ``positions`` (K, 2) and
    ``collision`` (a point or None).
    """
    nominals = list(dict.fromkeys(nominal for _, nominal in combos))
    figure = Figure(figsize=(2.9 * len(worlds) + 0.5, 6.2 * len(nominals)),
                    layout='constrained')
    axes = figure.subplots(len(nominals), len(worlds), squeeze=False)
    for row, nominal in zip(axes, nominals):
        for ax, world in zip(row, worlds):
            _draw_barn_world(ax, world)
            for name, combo_nominal in combos:
                trajectory = trajectories.get((world.world, name, combo_nominal))
                if combo_nominal != nominal or trajectory is None:
                    continue
                ax.plot(*trajectory['positions'].T, color=FILTER_COLORS.get(name, 'gray'),
                        linewidth=1.2, label=name)
                if trajectory['collision'] is not None:
                    ax.plot(*trajectory['collision'], 'x', color='red', markersize=8,
                            markeredgewidth=2)
            ax.set_title(f'world {world.world}, {nominal}', fontsize=9)
    axes[0, 0].legend(loc='lower right', fontsize=6)
    figure.suptitle('BARN sample worlds: paths per filter (x: collision)')
    figure.savefig(path_png, dpi=80)


def barn_metric_figure(path_png, records, combos, baseline_metric):
    """Histogram of BARN's metric over the successful runs, per filter x nominal."""
    figure = Figure(figsize=(7.5, 4.5), layout='constrained')
    ax = figure.subplots()
    bins = np.linspace(0.0, 0.5, 21)
    for name, nominal in combos:
        group = [r for r in records if r['filter'] == name and r['nominal'] == nominal]
        metrics = [r['barn_metric'] for r in group if r['success']]
        mean = np.mean([r['barn_metric'] for r in group])
        ax.hist(metrics, bins=bins, histtype='step', linewidth=1.5,
                color=FILTER_COLORS.get(name, 'gray'), linestyle=NOMINAL_STYLES.get(nominal),
                label=f'{name} / {nominal}: {len(metrics)}/{len(group)} succeeded, '
                f'mean {mean:.3f}')
    ax.axvline(baseline_metric, color='black', linestyle=':', linewidth=1.0,
               label=f'DWA mean over all runs ({baseline_metric:.3f})')
    ax.set_xlabel('BARN metric of a successful run (failures score 0)')
    ax.set_ylabel('worlds')
    ax.legend(fontsize=7)
    ax.grid(True, linewidth=0.3)
    figure.savefig(path_png, dpi=90)


DYNAMIC_OUTCOME_COLORS = {'success': 'tab:green', 'contact_at_fault': 'tab:red',
                          'contact_passive': 'tab:orange', 'timeout': '0.6'}


def dynamic_outcomes_figure(path_png, rows):
    """Stacked bars per filter x nominal x source and difficulty: shares of each outcome.

    ``rows`` are ``dynamic_suite.aggregate_dynamic`` rows (a row per difficulty and 'all').
    """
    labels = [f'{r["filter"]}\n{r["nominal"]}, {r["obstacle_source"]}\n{r["difficulty"]}'
              for r in rows]
    figure = Figure(figsize=(max(6.0, 1.0 * len(labels) + 1.5), 5.0), layout='constrained')
    ax = figure.subplots()
    x = np.arange(len(labels))
    bottom = np.zeros(len(labels))
    for outcome, color in DYNAMIC_OUTCOME_COLORS.items():
        shares = np.array([r[outcome] / r['runs'] for r in rows])
        ax.bar(x, shares, 0.7, bottom=bottom, color=color, label=outcome.replace('_', ' '))
        bottom += shares
    for index, r in enumerate(rows):
        share = r['success'] / r['runs']
        ax.annotate(f'{share:.2f}', (index, share / 2), ha='center', va='center', fontsize=8)
    ax.set_xticks(x, labels, fontsize=7)
    ax.set_ylim(0.0, 1.0)
    ax.set_ylabel('share of worlds')
    ax.grid(True, axis='y', linewidth=0.3)
    ax.legend(loc='upper center', bbox_to_anchor=(0.5, -0.2), ncols=4, fontsize=8)
    ax.set_title('Dynamic worlds: outcomes per difficulty')
    figure.savefig(path_png, dpi=90)


def _draw_dynamic_world(ax, world, end_time, contact):
    """Draw a dynamic world's course, start, goal, cylinder loops and cylinders at ``end_time``."""
    (x0, y0), (x1, y1) = COURSE
    ax.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, edgecolor='0.5',
                           linewidth=0.6, linestyle='--'))
    for trajectory in world.cylinders:
        ax.plot(*trajectory.points(16).T, color='0.6', linewidth=0.6)
    touched = None if contact is None else contact['cylinder']
    circles = [Circle(c.position(end_time), CYLINDER_RADIUS) for c in world.cylinders]
    colors = ['tab:red' if f'cylinder_{i}' == touched else 'lightsteelblue'
              for i in range(len(circles))]
    ax.add_collection(PatchCollection(circles, facecolor=colors, edgecolor='0.2', alpha=0.7,
                                      linewidth=0.5))
    ax.plot(*START[:2], 'ok', markersize=4)
    ax.plot(*GOAL, '*k', markersize=9)
    ax.add_patch(Circle(GOAL, 1.0, fill=False, edgecolor='0.4', linewidth=0.6))
    ax.set_xlim(x0 - 1.0, x1 + 1.0)
    ax.set_ylim(y0 - 1.0, y1 + 1.0)
    ax.set_aspect('equal')
    ax.tick_params(labelsize=7)


def dynamic_trajectories_figure(path_png, worlds, trajectories, combos):
    """Grid of sample worlds: the cylinders' loops and where they were when the run ended.

    One panel per world (``DynamicWorld``), every (filter, nominal) of ``combos`` drawn;
    cylinders at the end of the first combo's run (red: the one touched).
    ``trajectories[(world id, filter, nominal)]`` holds ``positions`` (K, 2),
    ``end_time`` [s] and ``contact`` (None or the referee's contact).
    """
    columns = min(3, max(1, len(worlds)))
    rows = math.ceil(len(worlds) / columns)
    figure = Figure(figsize=(5.2 * columns, 3.6 * rows + 0.4), layout='constrained')
    axes = np.atleast_1d(figure.subplots(rows, columns, squeeze=False).ravel())
    for ax in axes[len(worlds):]:
        ax.set_visible(False)
    for ax, world in zip(axes, worlds):
        runs = [(name, nominal, trajectories.get((world.world, name, nominal)))
                for name, nominal in combos]
        runs = [run for run in runs if run[2] is not None]
        first = runs[0][2] if runs else {'end_time': 0.0, 'contact': None}
        _draw_dynamic_world(ax, world, first['end_time'], first['contact'])
        for name, nominal, trajectory in runs:
            ax.plot(*trajectory['positions'].T, color=FILTER_COLORS.get(name, 'tab:blue'),
                    linestyle=NOMINAL_STYLES.get(nominal, '-'), linewidth=1.3,
                    label=f'{name} / {nominal}')
            if trajectory['contact'] is not None:
                ax.plot(*trajectory['contact']['robot_position'], 'x', color='red',
                        markersize=8, markeredgewidth=2)
        contact = first['contact']
        outcome = 'no contact' if contact is None else f'contact, {contact["kind"]}'
        outcome = outcome.replace('_', ' ')
        ax.set_title(f'world {world.world} ({world.difficulty}, {len(world.cylinders)} '
                     f'cylinders): {outcome} at {first["end_time"]:.1f} s', fontsize=8)
    if len(worlds):
        axes[0].legend(loc='lower right', fontsize=6)
    figure.suptitle('Dynamic sample worlds: loops (grey), cylinders at the end of the run '
                    '(red: touched), paths (x: contact)')
    figure.savefig(path_png, dpi=80)
