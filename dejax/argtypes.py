"""argparse value types shared by the command lines of dejax and fitting: each converts one
option's text and names the option in its error (exit code 2 through argparse)."""
from __future__ import annotations

import argparse


def _number(name, convert, what, accept, bound):
    """argparse type: ``convert(text)`` (float or int) that passes ``accept``; errors name the
    option, say it must be ``what`` ("a number") and, when out of range, ``bound`` (">= 0")."""

    def conv(text):
        try:
            v = convert(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be {what}, got {text!r}") from None
        if not accept(v):
            raise argparse.ArgumentTypeError(f"{name} must be {bound}, got {text}")
        return v

    return conv


def positive(name):
    """argparse type: a number > 0."""
    return _number(name, float, "a number", lambda v: v > 0, "> 0")


def int_at_least(name, lowest: int):
    """argparse type: a whole number >= ``lowest``."""
    return _number(name, int, "a whole number", lambda v: v >= lowest, f">= {lowest}")


def positive_int(name):
    """argparse type: a whole number >= 1."""
    return int_at_least(name, 1)


def nonneg(name):
    """argparse type: a number >= 0."""
    return _number(name, float, "a number", lambda v: not v < 0, ">= 0")


def float_list(name):
    """argparse type: comma-separated numbers, e.g. ``10,30,50`` -> [10.0, 30.0, 50.0]."""

    def conv(text):
        parts = [v.strip() for v in text.split(",") if v.strip()]
        try:
            values = [float(v) for v in parts]
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be comma-separated numbers, got {text!r}") from None
        if not values:
            raise argparse.ArgumentTypeError(f"{name} needs at least one number, got {text!r}")
        return values

    return conv


def mesh_shape(text):
    """argparse type: an element grid such as ``12x20x4`` -> (12, 20, 4)."""
    parts = text.lower().split("x")
    try:
        shape = tuple(int(p) for p in parts)
    except ValueError:
        shape = ()
    if len(shape) != 3 or min(shape) < 1:
        raise argparse.ArgumentTypeError(f"mesh must look like 12x20x4 (three positive integers), got {text!r}")
    return shape


def rho_inf(text):
    """argparse type: the generalized-alpha spectral radius, in [0, 1]."""
    v = nonneg("--rho-inf")(text)
    if v > 1:
        raise argparse.ArgumentTypeError(f"--rho-inf must lie in [0, 1], got {text}")
    return v
