"""Sampling: DDPM, DDIM and the few-step solvers DPM-Solver++(2M) (ODE and SDE) and UniPC, with classifier-free guidance
and editing masks, and the settings shared by every caller."""

from dgsdp.sampling.noise import Noise
from dgsdp.sampling.sampler import METHODS, Condition, Guidance, PreparedCondition, Sampler, check_method
from dgsdp.sampling.settings import GuidanceSettings, SamplingSettings
from dgsdp.sampling.solvers import SOLVERS, DPMSolverPP2M, DPMSolverPP2MSDE, UniPC, make_solver, solver_timesteps

__all__ = [
    "METHODS",
    "SOLVERS",
    "Condition",
    "DPMSolverPP2M",
    "DPMSolverPP2MSDE",
    "Guidance",
    "GuidanceSettings",
    "Noise",
    "PreparedCondition",
    "Sampler",
    "SamplingSettings",
    "UniPC",
    "check_method",
    "make_solver",
    "solver_timesteps",
]
