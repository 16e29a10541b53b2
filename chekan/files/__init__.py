"""What chekan does with the files it writes: durably (:mod:`chekan.files.durable`),
never over an input or a measurement (:mod:`chekan.files.outputs`), each kind under its own
names (:mod:`chekan.files.kinds`)."""
