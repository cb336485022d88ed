"""Training: what one run is (:mod:`.config`: method options, the run configuration, profiles), the
one generic loop of every network method (:mod:`.loop`) and faster CPU backward passes
(:mod:`.conv_grad`). Knows no method: each method's recipe lives with the method."""
