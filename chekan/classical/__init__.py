"""The classical method of Calibr.exe (:mod:`chekan.classical.fit`, the paper's eqs. 16–25)
and what the sensor's lag leaves in the hold means it reads (:mod:`chekan.classical.settling`)."""
