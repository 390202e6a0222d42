"""The orchestration layer: the benchmark's main job (``containergym-marl compare``) and the Ray
sweep under it, above training and evaluation.

* :mod:`.compare_args` — what a comparison is asked (:class:`CompareArgs`, also the CLI's options);
* :mod:`.plan` and :mod:`.shipped` — what it has to do, as data, from the files alone;
* :mod:`.sweep` — executing a plan on Ray (:mod:`.tasks`, :mod:`.cluster`, :mod:`.progress`,
  :mod:`.ray_reaper`);
* :mod:`.compare` — plan, execute, report (tables, figures: :mod:`.figures`);
* :mod:`.publish` — publishing a sweep's runs and evaluations, and bringing them back;
* :mod:`.stopping` — a study script stopped by SIGTERM stops its child processes first.
"""

from containergym_marl.orchestration.compare import compare
from containergym_marl.orchestration.compare_args import (
    PAPER_METHODS,
    PAPER_ROWS,
    QUICK_TIMESTEPS,
    SHIPPED,
    CompareArgs,
)

__all__ = ["PAPER_METHODS", "PAPER_ROWS", "QUICK_TIMESTEPS", "SHIPPED", "CompareArgs", "compare"]
