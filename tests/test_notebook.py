"""The example notebook (examples/plot_a_run.ipynb) runs from top to bottom: it runs the default
scenario, opens the run folder with railhil.open_run and plots it (nbclient, a real Jupyter kernel)."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOK = ROOT / "examples" / "plot_a_run.ipynb"


@pytest.mark.timeout(600)
def test_the_example_notebook_runs(tmp_path):
    nbformat = pytest.importorskip("nbformat", reason="nbformat is not installed (the test extra)")
    nbclient = pytest.importorskip("nbclient", reason="nbclient is not installed (the test extra)")
    pytest.importorskip("ipykernel", reason="ipykernel is not installed (the test extra): no kernel")
    nb = nbformat.read(NOTEBOOK, as_version=4)
    client = nbclient.NotebookClient(nb, timeout=300, kernel_name="python3",
                                     resources={"metadata": {"path": str(tmp_path)}})
    client.execute()
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])]
    assert not [o for o in outputs if o.get("output_type") == "error"]
    texts = " ".join(str(o.get("data", {}).get("text/plain", "")) for o in outputs)
    assert "stopping_distance_m" in texts and "RunFolder(" in texts
    figures = [o for o in outputs if "image/png" in o.get("data", {})]
    assert len(figures) >= 2          # the overview and the WSP cycle (the kernel's inline backend: PNG)
