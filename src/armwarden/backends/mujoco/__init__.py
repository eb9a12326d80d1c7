"""The MuJoCo backend (work in progress): real physics behind the backend contract.

Built so far: `model` (the MuJoCo model built from the same robot description as the Pinocchio
model, with the envelope's capsules as collision geometry). The backend class, its `Config` and
`create_backend` are not written yet, so the registry still lists "mujoco" as planned.
"""
