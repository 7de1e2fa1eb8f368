"""What a run reports: the foundation's KPIs from plant truth, its plots and the HTML report.

The studies add their own KPIs, summary lines and plots (hil/studies/<name>/kpis.py, plots.py); this
wing names none of them.
"""
