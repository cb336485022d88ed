"""Scores: image metrics in the paper's conventions (:mod:`.metrics`) and the training losses built
on them (:mod:`.losses`). Pure functions of tensors; imported by methods, training and experiments."""
