"""The learning side of procam, in floors; a module imports only from its own floor or below.

1. :mod:`compensation.scores`: image metrics and training losses (pure functions).
2. :mod:`compensation.data`: a rendered setup read as tensors.
3. :mod:`compensation.training`: what one training run is (options, configuration), the generic
   training loop and faster CPU backward passes.
4. :mod:`compensation.methods`: one module per method, each with its own training recipe, and the
   registry.
5. :mod:`compensation.experiments`: run directories, closed loop, the jobs and the one planner of
   studies and benches, executors, the official output layout.
6. :mod:`compensation.reports`: summaries, charts, tables and the HTML report of a folder.
7. :mod:`compensation.demo` and :mod:`compensation.cli` on top.
"""
