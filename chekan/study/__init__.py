"""Studies on simulated sessions: the coverage and accuracy study
(:mod:`chekan.study.coverage`, ``python -m chekan.study``), its scenario, summary and
figures, and the comparison of two programs (``python -m chekan.study.compare``)."""
