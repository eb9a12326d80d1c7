"""The core: value types and pure functions every layer may use, importing nothing of ArmWarden's
own outside this package (errors, timed trajectories, measured state, geometric predicates)."""
