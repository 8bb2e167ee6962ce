"""Campaigns: every procedure run on a board, then the analysis, then one report.

Above the bench (which runs one procedure) and the analysis (fit, validate, diagnose, design),
calling both as functions; the command line hands it its analysis stages (`cli/stages.py`) and
this package never imports the command line.

- `run`: the fixed campaign (the four procedure files, the stages, report.md/html, plots).
- `adaptive`: the adaptive campaign (plan, run, fit, re-plan until the target SEs are met).
- `answer`, `summary`, `html_report`: the campaign's answer, its terminal summary, report.html.
"""
