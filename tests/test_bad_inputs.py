"""The bad-input table (:mod:`badinputs`): every row stops as the README says, with
one line naming the file and the key or column and nothing written, or (valid but suspicious
data) gets its plausibility note. ``bench/bad_inputs.py`` re-runs the table and prints counts."""

from __future__ import annotations

import pytest
from badinputs import all_cases, run_case, workflow_copy

CASES = all_cases()


def _param(case):
    marks = [pytest.mark.workflow] if case.kind == "workflow" else []
    return pytest.param(case, id=f"{case.area}: {case.id}", marks=marks)


@pytest.fixture(scope="module")
def workflow_dir(tmp_path_factory):
    return workflow_copy(tmp_path_factory.mktemp("badinput-workflow"))


def test_the_table_is_wide():
    areas = {c.area for c in CASES}
    assert (
        len(CASES) >= 170 and {"config", "set", "scenario", "npz", "csv", "output", "cli", "note", "workflow"} <= areas
    )


@pytest.mark.parametrize("case", [_param(c) for c in CASES])
def test_bad_input(case, tmp_path, request):
    wd = request.getfixturevalue("workflow_dir") if case.kind == "workflow" else None
    out = run_case(case, tmp_path, workflow_dir=wd)
    if out.verdict == "skipped":
        pytest.skip(out.detail)
    assert out.verdict == "ok", f"{out.verdict}: {out.detail}"
