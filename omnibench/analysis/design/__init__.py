"""Experiment design: which steps to run next so the fit's target parameters reach their SE
at the least cost in robot seconds and operator actions (docs/design.md).

    space.build_space(...)             the candidate steps the lab can run, within the limits
    information.candidate_information  Fisher information of each candidate (fit's sensitivities)
    planner.plan(robot, fit, targets, space, costs) -> Design   greedy weighted A-optimal plan
    files.write_procedures(design, ...) -> procedure files the runner executes unchanged
"""
