"""Sampling: DDPM, DDIM and the few-step solvers DPM-Solver++(2M) (ODE and SDE) and UniPC, with classifier-free guidance
and editing masks."""

from dgsdp.sampling.noise import Noise
from dgsdp.sampling.sampler import METHODS, Condition, Guidance, PreparedCondition, Sampler, check_method
from dgsdp.sampling.solvers import SOLVERS, DPMSolverPP2M, DPMSolverPP2MSDE, UniPC, make_solver, solver_timesteps

__all__ = [
    "METHODS",
    "SOLVERS",
    "Condition",
    "DPMSolverPP2M",
    "DPMSolverPP2MSDE",
    "Guidance",
    "Noise",
    "PreparedCondition",
    "Sampler",
    "UniPC",
    "check_method",
    "make_solver",
    "solver_timesteps",
]
