"""The evaluation: closed-loop suites in lockstep, their records, tables and plots.

Layout, from the command line down (no module imports one above it)::

    cli             ``evaluate``: parse, dispatch to a suite, print and write
    scenario_suite  scenarios x filters x seeds       (runs ``sim_bridge.closed_loop``)
    barn_suite      the 200 BARN worlds               (``sim_bridge.barn``)
    dynamic_suite   the 60 moving-cylinder worlds     (``sim_bridge.dynamic_worlds``)
    parallel_runs   worlds over worker processes, one progress bar
    arguments       the options every suite shares (filters, -p, actuation, lidar)
    reports         tables, findings, results.json / results.md and plots
    records         one record per run and the statistics of the filter
    progress        the progress bar

It may import ``polyc2bf_ros`` and the rest of ``sim_bridge``; nothing outside this
package imports it but tests and benchmarks.
"""
