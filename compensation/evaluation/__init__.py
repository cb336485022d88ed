"""Evaluation: image metrics (:mod:`.metrics`), training losses built on them (:mod:`.losses`),
closed-loop scoring through the simulator (:mod:`.closed_loop`) and the benchmark (:mod:`.bench`,
:mod:`.tables`)."""
