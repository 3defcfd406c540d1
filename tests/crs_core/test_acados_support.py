"""acados from its wheel: where its solvers go, that loading it leaves the pinned casadi (and
IPOPT) alone, and the one-line error without it."""

from __future__ import annotations

import sys

import pytest

from crs_core import acados_support


def test_a_solver_has_a_folder_of_its_own_in_the_compile_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("CRS_CACHE_DIR", str(tmp_path))
    folder = acados_support.solver_dir("mpcc_test")
    assert folder.is_relative_to(tmp_path) and folder.parts[-2:] == ("acados", "mpcc_test")
    assert folder.is_dir()


def test_without_the_wheel_the_error_says_how_to_install_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "acados", None)  # import acados -> ImportError
    with pytest.raises(acados_support.AcadosUnavailable, match=r"run\.sh setup"):
        acados_support.acados_template()


def test_loading_acados_keeps_the_pinned_casadi_and_its_ipopt():
    import casadi as ca

    try:
        template = acados_support.acados_template()
    except acados_support.AcadosUnavailable as error:  # pragma: no cover - set-up dependent
        pytest.skip(str(error))
    assert hasattr(template, "AcadosOcpSolver")
    assert ca.__version__ == "3.8.2"
    x = ca.SX.sym("x")
    solver = ca.nlpsol(
        "s", "ipopt", {"x": x, "f": (x - 1) ** 2}, {"ipopt.print_level": 0, "print_time": 0}
    )
    assert float(solver(x0=0)["x"]) == pytest.approx(1.0)
