"""The ``chekan-result/1`` document (:mod:`chekan.results.document`: build, write, read,
check) and its plain-text summary (:mod:`chekan.results.summary`)."""
