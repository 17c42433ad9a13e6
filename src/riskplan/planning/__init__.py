"""Planners: the simulator RRT and LQG-MP plan selection for deformable tissue (Patil et al.
2011, section IV), and the chest-cavity planners (PRM, Bayesian optimisation)."""
