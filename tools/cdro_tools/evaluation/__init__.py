"""Evaluation of anchor-free maps against ground truth: the library behind cdro-eval.

Import what you need from here (docs/tools.md, cdro-eval, describes the choices):

    from cdro_tools import evaluation as ev
    bad = []
    truth_xy, truth_z = ev.read_truth("nodes.csv", bad)
    ranges = ev.project_ranges(ev.read_ranges("ranges.csv", bad), truth_z).ranges
    links = ev.Links.from_ranges(ranges.links())
    for result in ev.run_baselines(links, ["mds", "lsq-huber", "lsq-drop"], f_scale_m=0.175):
        print(result.name, ev.align(result.positions_m, truth_xy).rmse_m)
    print(ev.anchor_free_crb(truth_xy, links.pairs, sigma_m=0.13).rmse_m)
"""
from .alignment import Alignment, align, rigid_fit, rmse
from .baselines import (DROP_THRESHOLD_M, HUBER_K, NAMES as BASELINE_NAMES, BaselineError, BaselineResult, Links,
                        LsqSolution, components, mds_map, run_baselines, solve_lsq)
from .convergence import RmsePoint, all_converged_at, convergence_ranges, rmse_over_ranges
from .crb import CrbResult, anchor_free_crb, fisher_information
from .inputs import (BadRow, InputError, NodeEstimate, Projection, Ranges, project_ranges, read_estimates,
                     read_heights, read_ranges, read_trace, read_truth)

__all__ = [
    "Alignment", "align", "rigid_fit", "rmse",
    "DROP_THRESHOLD_M", "HUBER_K", "BASELINE_NAMES", "BaselineError", "BaselineResult", "Links", "LsqSolution",
    "components", "mds_map", "run_baselines", "solve_lsq",
    "RmsePoint", "all_converged_at", "convergence_ranges", "rmse_over_ranges",
    "CrbResult", "anchor_free_crb", "fisher_information",
    "BadRow", "InputError", "NodeEstimate", "Projection", "Ranges", "project_ranges", "read_estimates",
    "read_heights", "read_ranges", "read_trace", "read_truth",
]
