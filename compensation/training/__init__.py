"""Training: the run configuration (:mod:`.config`), the one loop of every network method
(:mod:`.loop`) and run directories (:mod:`.runs`)."""
