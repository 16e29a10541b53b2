"""``python -m chekan.study``: the coverage and accuracy study (:mod:`chekan.study.coverage`)."""

from chekan.study.coverage import main

raise SystemExit(main())
