"""Campaigns: every procedure run on a board, then the analysis, then one report.

Above the bench (which runs one procedure) and the analysis (fit, validate, diagnose, design),
calling both as functions; this package never imports the command line.

- `analysis_commands`: what `omnibench fit` and `validate-energy` do, as functions; `diagnose_command`: what `omnibench diagnose` does
  (read the runs, fit/validate/diagnose, write the model file and plots), called by those
  commands and by the campaign's stages.
- `stages`: the campaign's analysis stages (fit, validate-energy, diagnose in turn, each one's
  record for the report; Ctrl-C marks the interrupted one).
- `run`: the fixed campaign (every registered procedure, the stages, report.md/html, plots).
- `adaptive`: the adaptive campaign (plan, run, fit, re-plan until the target SEs are met).
- `answer`, `summary`, `html_report`: the campaign's answer, its terminal summary, report.html.
"""
