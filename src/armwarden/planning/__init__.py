"""Motion planning: timed joint trajectories and the joint, pose and Cartesian planners.

Planners only build trajectories; they never decide whether a motion is allowed. That is the
envelope's job (`armwarden.safety.envelope`), and the Guard runs it on every plan.
"""
