"""A parameter documented once in a shared type hint (``Doc``) is documented wherever used."""

from dataclasses import dataclass
from typing import Annotated

from lcpbench.core.specs import Bounds, CheckedParams, Doc, describe_params

Width = Annotated[int, Bounds(ge=1), Doc("Width of every instance.")]


@dataclass(frozen=True)
class _Plain(CheckedParams):
    """Parameters of a family that says nothing of its width."""

    width: Width = 3


@dataclass(frozen=True)
class _Own(CheckedParams):
    """Parameters of a family with its own word on the width.

    Parameters
    ----------
    width : int
        Width, at least 2 here.
    """

    width: Annotated[int, Bounds(ge=2), Doc("Width of every instance.")] = 4


def test_the_hint_documents_a_field_the_docstring_leaves_out():
    assert describe_params(_Plain) == [("width", "int", 3, "Width of every instance.")]


def test_the_class_docstring_takes_precedence():
    assert describe_params(_Own)[0][3] == "Width, at least 2 here."


def test_every_shipped_family_documents_its_size():
    from lcpbench.core.registry import problems
    shipped = {n: i for n, i in problems().items()
               if i.func.__module__.startswith("lcpbench.problems.")}
    assert "inexact" in shipped and "spd-cond" in shipped
    for name, info in shipped.items():
        for field, _type, _default, doc in describe_params(info.params):
            if field == "n":
                assert doc, f"{name}: parameter n has no documentation"
