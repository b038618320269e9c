"""The model's constants, the one source of truth: numbers only, so that any part of the lab (the
exercise's sandbox too) can read them without the model's code (mazelab.model shows them with it)."""

import math

import numpy as np

# -- the paper's and the lab's (a student may change them here) -----------------------------------
ROBOT_SPEED = 0.2  # L, the step length in map units
MAX_STRAIGHT_STEPS = 32  # the robot picks a new heading after this many straight steps (paper: 10 or 32)
OUTSIDE_PENALTY = 0.5  # likelihood factor for particles outside the free area (refinement 1)
RPF_THRESHOLD = 0.2  # RPF regularises when ESS < N_T = RPF_THRESHOLD * N_S (refinement 5)
CONFIDENCE_RADIUS = 1.0  # the estimate is "confident" when CONFIDENCE_SHARE of the mass lies this close
CONFIDENCE_SHARE = 0.95
CONVERGENCE_RADIUS = 0.5  # a run has converged from the step after which its error stays below this
DEFAULT_PARTICLE_COUNT = 1500
DEFAULT_STEPS = 200
DEFAULT_SIGMA, DEFAULT_DELTA = 0.3, 0.5  # the example's noise std (map units) and compass error (radians)

# exp(x) is 0 in float64 below this: when the filter's whole predictive likelihood p(z_k | z_1:k-1)
# is that small no particle explains z_k, and the filter starts again from the prior.
LOG_UNDERFLOW = math.log(np.finfo(float).tiny)
# Particle positions and headings are float32 (half the memory traffic of float64; the map is at most
# a few hundred units, where float32 resolves 1e-5). The robot's own path stays float64 and exact.
PARTICLE_DTYPE = np.float32
