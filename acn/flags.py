"""Config dataclasses as command-line flags: the one mapping every ``acn-*`` command uses.

A command lists the fields of its config it exposes, each as a ``Flag`` (the help text, and where
the field's type is not enough, how to parse the text); ``add_flags`` declares them on an
``argparse`` parser with the config's own defaults, and ``config_from_args`` builds the config back
from the parsed arguments. A field's option is ``--field-name`` unless the ``Flag`` names another,
so defaults, names and types are written once, in the dataclass::

    FLAGS = {"epochs": Flag("passes over the data", positive_int), "lr": Flag("Adam learning rate")}
    add_flags(parser, FitConfig(), FLAGS)
    cfg = config_from_args(args, FitConfig(), FLAGS)

The number parsers here (``positive_int``, ``seconds``, ...) refuse what no setting of this toolkit
means (NaN, infinity, past 1e9) in one line, as ``argparse`` errors.
"""

from __future__ import annotations

import argparse
import dataclasses
import types
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence


def number(kind: type, minimum: float, inclusive: bool, maximum: float = 1e9) -> Callable[[str], float]:
    """An argparse type: a finite ``kind`` (int or float) >= or > ``minimum`` and <= ``maximum``
    (by default 1e9: past it every setting of this toolkit is a typo, and some overflow)."""
    word = "a whole number" if kind is int else "a number"
    bound = f"{'>=' if inclusive else '>'} {minimum:g} and <= {maximum:g}"

    def parse(text: str):
        try:
            v = kind(text)
        except (ValueError, OverflowError):
            raise argparse.ArgumentTypeError(f"expected {word}, got {text!r:.40}") from None
        if not (v == v and abs(v) != float("inf")) or v < minimum or (v == minimum and not inclusive) or v > maximum:
            raise argparse.ArgumentTypeError(f"expected a finite number {bound}, got {text:.40}")
        return v

    return parse


positive_int = number(int, 1, inclusive=True)
nonneg_int = number(int, 0, inclusive=True)
positive_float = number(float, 0, inclusive=False)
nonneg_float = number(float, 0, inclusive=True)
finite_float = number(float, -1e9, inclusive=True)
seconds = number(float, 0, inclusive=False, maximum=86_400)  # an episode: up to a day


def comma_list(item: Callable[[str], Any], length: int | None = None) -> Callable[[str], tuple]:
    """An argparse type: comma-separated values, each parsed by ``item`` (exactly ``length`` of them
    where given)."""

    def parse(text: str) -> tuple:
        values = tuple(item(t.strip()) for t in text.split(","))
        if length is not None and len(values) != length:
            raise argparse.ArgumentTypeError(f"expected {length} comma-separated values, got {len(values)} in {text!r:.60}")
        return values

    return parse


@dataclass(frozen=True)
class Flag:
    """How one config field appears on the command line."""

    help: str
    parse: Callable[[str], Any] | None = None  # text -> value (default: from the field's type)
    option: str | None = None                   # the option (default: --field-name)
    choices: Sequence[Any] | None = None
    metavar: str | None = None


def option_of(name: str, flag: Flag) -> str:
    return flag.option or "--" + name.replace("_", "-")


def _dest(name: str, flag: Flag) -> str:
    return option_of(name, flag).lstrip("-").replace("-", "_")


def _parser_for(kind: Any) -> tuple[Callable[[str], Any] | None, bool]:
    """(the argparse type for a field annotation, whether it is a yes/no switch)."""
    args = [a for a in typing.get_args(kind) if a is not type(None)]
    if typing.get_origin(kind) in (typing.Union, types.UnionType) and len(args) == 1:
        kind = args[0]  # X | None: parse X
    if kind is bool:
        return None, True
    if kind is int:
        return nonneg_int, False
    if kind is float:
        return finite_float, False
    if kind is Path:
        return Path, False
    if typing.get_origin(kind) is tuple:
        items = typing.get_args(kind)
        if len(items) == 2 and items[1] is Ellipsis:
            return comma_list(_parser_for(items[0])[0] or str), False
        return comma_list(_parser_for(items[0])[0] or str, len(items)), False
    return None, False  # str


def _defaults(config: Any) -> dict[str, Any]:
    """Field name -> default of a dataclass instance, or of a dataclass type (``MISSING``: none)."""
    if isinstance(config, type):
        return {f.name: (f.default if f.default is not dataclasses.MISSING else
                         f.default_factory() if f.default_factory is not dataclasses.MISSING else dataclasses.MISSING)
                for f in dataclasses.fields(config)}
    return {f.name: getattr(config, f.name) for f in dataclasses.fields(config)}


def add_flags(parser: argparse.ArgumentParser | argparse._ArgumentGroup, config: Any,
              flags: Mapping[str, Flag]) -> None:
    """Declare ``flags`` (field name -> ``Flag``) of ``config``: a dataclass instance, whose values
    are the defaults, or a dataclass type, whose fields without a default become required options."""
    kinds, defaults = typing.get_type_hints(config if isinstance(config, type) else type(config)), _defaults(config)
    for name, flag in flags.items():
        if name not in kinds:
            raise TypeError(f"{getattr(config, '__name__', type(config).__name__)} has no field {name!r}")
        parse, switch = _parser_for(kinds[name])
        option = option_of(name, flag)
        kw: dict[str, Any] = dict(help=flag.help)
        if not option.startswith("-"):  # a positional argument
            kw["type"] = flag.parse or parse
            parser.add_argument(option, **kw)
            continue
        kw["dest"] = _dest(name, flag)
        if defaults[name] is dataclasses.MISSING:
            kw["required"] = True
        else:
            kw["default"] = defaults[name]
        if switch:
            kw["action"] = argparse.BooleanOptionalAction
        else:
            kw["type"] = flag.parse or parse
            if flag.choices is not None:
                kw["choices"] = flag.choices
            if flag.metavar is not None:
                kw["metavar"] = flag.metavar
        parser.add_argument(option, **kw)


def config_from_args(args: argparse.Namespace, config: Any, flags: Mapping[str, Flag], **fields: Any) -> Any:
    """``config`` (an instance) with every field in ``flags`` set from ``args`` and ``fields`` as
    given; for a dataclass type, a new instance of it from them."""
    values = {name: getattr(args, _dest(name, flag)) for name, flag in flags.items()} | fields
    return config(**values) if isinstance(config, type) else dataclasses.replace(config, **values)


def given(args: argparse.Namespace, parser: argparse.ArgumentParser) -> set[str]:
    """The options (their ``dest`` names) the user set to something other than their default."""
    return {k for k, v in vars(args).items() if v != parser.get_default(k)}


def given_fields(args: argparse.Namespace, parser: argparse.ArgumentParser, flags: Mapping[str, Flag]) -> set[str]:
    """The config fields among ``flags`` whose options the user set to something other than their default."""
    chosen = given(args, parser)
    return {name for name, flag in flags.items() if _dest(name, flag) in chosen}
