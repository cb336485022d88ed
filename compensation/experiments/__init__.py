"""Experiments: run directories (:mod:`.runs`), closed-loop scoring through the simulator
(:mod:`.closed_loop`), the jobs of studies and benches (:mod:`.jobs`), the one planner that turns a
study or a bench into them (:mod:`.plans`, :mod:`.studies`, :mod:`.bench`), where jobs run
(:mod:`.executors`) and the official code's output layout (:mod:`.official`)."""
