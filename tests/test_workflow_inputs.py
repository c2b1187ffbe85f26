"""Bad input through the workflow (issue 24): a failed job's log holds the reason; a bad config
stops the workflow at parse time naming the file and the key, before any job."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import ROOT, copy_repo, run_snakemake

pytestmark = pytest.mark.workflow


def test_a_failed_job_says_why_in_its_log(tmp_path):
    copy_repo(tmp_path)
    z = dict(np.load(ROOT / "resources" / "rig_demo.npz"))
    z["x_meas"] = z["x_meas"].copy()
    z["x_meas"][100] = np.nan
    np.savez(tmp_path / "bad.npz", **z)
    (tmp_path / "bad.yaml").write_text("closeloop: {datasets: {bad: bad.npz}, default_dataset: bad}\n")
    r = run_snakemake(tmp_path, "results/closeloop/bad/closeloop.json", "--cores", "1",
                      "--configfile", "config.yaml", "bad.yaml", check=False)
    assert r.returncode == 1
    line = "ssamb closeloop: error: bad.npz: column 'x_meas' has 1 non-finite value(s)"
    log = (tmp_path / "results" / "logs" / "closeloop" / "bad.log").read_text()
    assert line in log and "Traceback" not in log
    assert line in r.stderr and "lost sys.stderr" not in r.stderr
    assert not (tmp_path / "results" / "closeloop").exists()
