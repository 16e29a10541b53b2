"""The instrument and what exercises it: the forward model of both quartz torsion systems
(:mod:`chekan.physics.sensor`, the paper's eqs. 1–15), units at the edges
(:mod:`chekan.physics.units`), the parameters a calibration reports
(:mod:`chekan.physics.parameters`) and the tilt programs (:mod:`chekan.physics.program`)."""
