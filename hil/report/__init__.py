"""What a run reports: the foundation's KPIs from plant truth, its plots and the HTML report, from the run
folder the runtime left (hil.report.run: finish_run, and the entry points that run a scenario and report it).

The studies add their own KPIs, summary lines and plots (hil/studies/<name>/kpis.py, plots.py); this
wing names none of them.
"""
