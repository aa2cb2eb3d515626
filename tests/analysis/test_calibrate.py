"""The accelerometer scale fit (seed §D, eq 7) on the seed's own TABLE I and II."""

from __future__ import annotations

import math

import pytest

from mkflight.analysis.calibrate import (
    CalibrationInputError,
    CalibrationRow,
    fit_acc_scale,
    parse_rows,
)
from mkflight.errors import MkflightError
from tests.analysis.seed_tables import (
    TABLE_I_MEAN,
    TABLE_I_RUNS,
    TABLE_II_MEAN,
    TABLE_II_RUNS,
    as_text,
)


def test_table_i_gives_the_seeds_k_nick() -> None:
    """TABLE I's three measurement runs (33 rows) fit k = 606.3 counts/g, as the seed prints."""
    fit = fit_acc_scale(parse_rows(as_text(TABLE_I_RUNS), "table1"))
    assert len(fit.rows) == 33
    assert round(fit.k_counts_per_g, 1) == 606.3
    assert 11 < fit.residual_rms_counts < 12  # the ±15° rows are 30 counts apart


def test_table_ii_gives_the_seeds_k_roll() -> None:
    """TABLE II's three measurement runs (33 rows) fit k = 603.44 counts/g, as the seed prints.

    The seed's "Mean" row is truncated, not rounded (-164.67 printed as -164.6): with it
    included the fit gives 603.43, so the measurement runs alone are the seed's data.
    """
    fit = fit_acc_scale(parse_rows(as_text(TABLE_II_RUNS), "table2"))
    assert len(fit.rows) == 33
    assert round(fit.k_counts_per_g, 2) == 603.44
    with_mean = fit_acc_scale(parse_rows(as_text((*TABLE_II_RUNS, TABLE_II_MEAN)), "t2m"))
    assert round(with_mean.k_counts_per_g, 2) == 603.43
    with_mean_i = fit_acc_scale(parse_rows(as_text((*TABLE_I_RUNS, TABLE_I_MEAN)), "t1m"))
    assert round(with_mean_i.k_counts_per_g, 1) == 606.3


def test_fit_is_the_closed_form_and_errors_are_measured_minus_fit() -> None:
    rows = parse_rows(as_text(TABLE_I_RUNS), "t")
    fit = fit_acc_scale(rows)
    s = [math.sin(math.radians(r.angle_deg)) for r in rows]
    k = -sum(r.counts * si for r, si in zip(rows, s, strict=True)) / sum(si * si for si in s)
    assert fit.k_counts_per_g == pytest.approx(k, rel=1e-12)
    for row, err in zip(fit.rows, fit.errors_counts, strict=True):
        assert err == pytest.approx(row.counts - fit.fitted_counts(row))
    rms = math.sqrt(sum(e * e for e in fit.errors_counts) / len(rows))
    assert fit.residual_rms_counts == pytest.approx(rms)


def test_exact_data_fit_exactly() -> None:
    rows = [
        CalibrationRow(angle_deg=a, counts=-600.0 * math.sin(math.radians(a)), line=i)
        for i, a in enumerate((-90.0, -30.0, 10.0, 75.0), start=1)
    ]
    fit = fit_acc_scale(rows)
    assert fit.k_counts_per_g == pytest.approx(600.0)
    assert fit.residual_rms_counts == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("sep", [" ", "\t", ",", ", ", "  \t "])
def test_separators_header_comments_and_blank_lines(sep: str) -> None:
    text = f"# tilt table\n\nangle_deg{sep}counts\n-90{sep}602  # first\n\n45{sep}-431.5\n"
    rows = parse_rows(text, "t.txt")
    assert rows == [
        CalibrationRow(angle_deg=-90.0, counts=602.0, line=4),
        CalibrationRow(angle_deg=45.0, counts=-431.5, line=6),
    ]


def test_no_header_is_fine() -> None:
    assert len(parse_rows(as_text(TABLE_I_RUNS, header=False), "t")) == 33


@pytest.mark.parametrize(
    ("text", "line"),
    [
        ("angle counts\n-90 602\n45 x\n", 3),
        ("-90 602\n45\n", 2),
        ("-90 602 7\n", 1),
        ("-90 602\nangle counts\n", 2),  # a header only as the first line
        ("-90 nan\n", 1),
        ("inf 602\n", 1),
        ("-90,602,\n", 1),
    ],
)
def test_malformed_row_names_file_and_line(text: str, line: int) -> None:
    with pytest.raises(CalibrationInputError, match=rf"^tilt\.csv:{line}: malformed row"):
        parse_rows(text, "tilt.csv")


def test_error_is_an_mkflight_error() -> None:
    assert issubclass(CalibrationInputError, MkflightError)


@pytest.mark.parametrize("text", ["", "\n# only a comment\n\n", "angle_deg counts\n"])
def test_no_rows_is_a_clear_error(text: str) -> None:
    with pytest.raises(CalibrationInputError, match=r"^empty\.txt: no data rows"):
        fit_acc_scale(parse_rows(text, "empty.txt"), "empty.txt")


def test_only_level_rows_cannot_give_k() -> None:
    with pytest.raises(CalibrationInputError, match="tilted rows"):
        fit_acc_scale(parse_rows("0 1\n0 -2\n", "flat"), "flat")
