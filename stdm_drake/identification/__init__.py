"""Identification of a robot's rigid-body parameters and joint friction from its data (white box).

    regressor   the inverse-dynamics regressor tau = Y(q, v, v̇) pi of the robot's description (Drake
                AutoDiff), with per-joint viscous, Coulomb and reflected-rotor-inertia columns
    fit         least squares on the identifiable (base) parameters, with condition number and
                covariance; the physically consistent fit (pseudo-inertia SDP, MathematicalProgram)
    identified  the identified robot as a file (`identified.yaml`) and as a model (`PlantModel` of the
                description with the identified parameters): usable wherever a model is
"""
