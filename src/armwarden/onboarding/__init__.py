"""`armwarden init`: from an arm's URDF or MJCF to a checked policy, with no hand-written step.

The description is loaded (`robot.description_files`), its arm chain inferred or chosen, every
link's collision geometry fitted with capsules and their self-collision pairs analysed
(`fitted.py`), the joint limits read (`limits.py`), a workspace derived from the arm's reach and
the table plane (`reach.py`), a collision-free home chosen (`home.py`), and one commented policy
written (`policy_text.py`) beside the fitted file and a picture of the arm at home
(`picture.py`). The policy is loaded and checked exactly as `armwarden check-policy` does before
anything is written in its place; the same input gives the same bytes.
"""

from armwarden.onboarding.run import InitOptions, InitResult, run_init

__all__ = ["InitOptions", "InitResult", "run_init"]
