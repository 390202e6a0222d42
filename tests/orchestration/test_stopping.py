"""A study's worker processes stop with it (containergym_marl.orchestration.stopping): SIGTERM ends
the study as Ctrl-C would, and its pool's workers end in the middle of their tasks rather than
finishing them beside a study started again."""

from __future__ import annotations

import textwrap

from containergym_marl.orchestration.stopping import worker_pool
from tests.helpers import sigterm_leaves_no_child

# a study of two workers whose tasks would run for ten minutes
STUDY = textwrap.dedent("""
    import time
    from containergym_marl.orchestration.stopping import exit_on_sigterm, worker_pool

    if __name__ == "__main__":
        exit_on_sigterm()
        with worker_pool(2) as pool:
            futures = [pool.submit(time.sleep, 600) for _ in range(4)]
            for future in futures:
                future.result()
""")


def test_sigterm_stops_the_pools_workers_in_their_tasks(tmp_path):
    script = tmp_path / "study.py"
    script.write_text(STUDY)
    # the workers are forked: their command line is the study's own
    sigterm_leaves_no_child([str(script)], lambda cmdline: "study.py" in cmdline, count=2, timeout_s=60)


def _square(x: int) -> int:
    return x * x


def test_a_pool_left_normally_finishes_its_tasks():
    with worker_pool(2) as pool:
        futures = [pool.submit(_square, x) for x in range(5)]
    assert [f.result() for f in futures] == [0, 1, 4, 9, 16]
