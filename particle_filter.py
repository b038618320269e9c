"""The lab's filters, as the paper names them: `from particle_filter import Robot, run_model`.

The robot is lost in a maze; SIR, auxiliary (APF) and regularised (RPF) particle filters find it
(Arulampalam, Maskell, Gordon, Clapp 2002, Algorithms 4-6, with the paper's refinements). This file
only gathers the names; where each thing's lines are:

    one step of every particle filter: RESAMPLE the    mazelab/smc.py, SMC.step (a dozen lines; the hooks
      runs it is time for, move, reweight                below it are what differs between the filters)
    resampling (systematic, the textbook; stratified,  mazelab/resampling.py, systematic_resample, ...
      multinomial, residual)                             (SMC.step -> SMC.ancestors -> there)
    SIR (Algorithm 4)                                  mazelab/filters.py, SIRParticleFilter: the defaults
    APF (Algorithm 5)                                  mazelab/filters.py, AuxiliaryParticleFilter.log_eta,
                                                         .reweight_resampled
    RPF (Algorithm 6)                                  mazelab/filters.py, RegularizedParticleFilter
                                                         .move_resampled (the jitter), .kernels
    the model: prior, transition (1), likelihood (3)   mazelab/model.py, LostRobot (the constants:
                                                         mazelab/constants.py); the measurement (2)-(3),
                                                         the robot's and the filters' alike: Sensor
    the weights (W, ESS, the log mean increment)       mazelab/weights.py, Weights
    the filters' options, the model and the backend    mazelab/filters.py, ParticleFilter
    Robot (wandering, the straight-run limit)          mazelab/robot.py, Robot.step
    what every filter provides (your own filter too)   mazelab/contract.py (worked example: docs/architecture.md)
    a filter's options, declared once                  mazelab/declaration.py, Option; each filter's `options`
    every filter by name, label and colour             mazelab/registry.py, SHIPPED (one entry each)
    the RPF's kernel (bandwidth optimal, multimodal)   mazelab/regularisation.py
    modes of a cloud, the mode estimate                mazelab/modes.py
    the exact grid Bayes filter (the reference)        mazelab/grid_filter.py, GridBayesFilter.step
    the extended Kalman filter (the baseline)          mazelab/kalman.py, ExtendedKalmanFilter.step
    recovery from kidnapping, KLD-sampling             mazelab/recovery.py, mazelab/resampling.py
    run_model and simulate                             mazelab/simulation.py (one run, run_model over it,
                                                         and record_steps, the loop that records each step)
    how a seed becomes a run's random draws            mazelab/seeding.py
    saving and loading scenarios                       mazelab/scenario.py

The constants the paper lets a student change (ROBOT_SPEED, MAX_STRAIGHT_STEPS, OUTSIDE_PENALTY,
RPF_THRESHOLD) are shown here; change them in mazelab/constants.py, where every part reads them.
"""

from mazelab.constants import MAX_STRAIGHT_STEPS, OUTSIDE_PENALTY, ROBOT_SPEED, RPF_THRESHOLD
from mazelab.filters import AuxiliaryParticleFilter, ParticleFilter, RegularizedParticleFilter, SIRParticleFilter
from mazelab.grid_filter import GridBayesFilter
from mazelab.kalman import ExtendedKalmanFilter
from mazelab.recovery import Recovery
from mazelab.resampling import KLDSampling
from mazelab.robot import Robot
from mazelab.scenario import Scenario, ScenarioError, load_scenario, save_scenario
from mazelab.simulation import RunResult, run_model, simulate

__all__ = [
    "MAX_STRAIGHT_STEPS",
    "OUTSIDE_PENALTY",
    "ROBOT_SPEED",
    "RPF_THRESHOLD",
    "AuxiliaryParticleFilter",
    "ExtendedKalmanFilter",
    "GridBayesFilter",
    "KLDSampling",
    "ParticleFilter",
    "Recovery",
    "RegularizedParticleFilter",
    "Robot",
    "RunResult",
    "SIRParticleFilter",
    "Scenario",
    "ScenarioError",
    "load_scenario",
    "run_model",
    "save_scenario",
    "simulate",
]
