"""Discover method plugins through entry points.

Groups (declared in ``pyproject.toml``, also by third-party packages):

- ``facegeom.deformers``   -> :class:`facegeom.interfaces.Deformer`
- ``facegeom.retargeters`` -> :class:`facegeom.interfaces.Retargeter`
- ``facegeom.fitters``     -> :class:`facegeom.interfaces.Fitter`
- ``facegeom.identity``    -> identity fitters: ``fit(model, targets)`` -> an
  :class:`~facegeom.methods.identity.IdentityFit` (``facegeom``: :class:`~facegeom.methods.identity.IdentityFitter`)

The CLI, the viewer and the comparison scripts list and build every method the
same way: ``create("deformers", "tangent", d=3)``. A kind may also be named in the
singular (``"deformer"``, ``"retargeter"``, ``"fitter"``), as :func:`facegeom.create` users do.
The kind ``"identity"`` is named after its entry-point group and has one spelling; it is
the only kind with a default method (:data:`DEFAULTS`): ``create("identity")`` builds
facegeom's own identity fitter.

Method specs: a registered name plus parameters, parsed from text like
``label=name:k=v,k=v`` (:func:`parse_method`, :func:`parse_methods`) and built
with :meth:`MethodSpec.build`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from importlib.metadata import entry_points

from facegeom.errors import InputError

KINDS = ("deformers", "retargeters", "fitters", "identity")
"""The method kinds: each is the entry-point group ``facegeom.<kind>``."""

_SINGULAR = {"deformers": "deformer", "retargeters": "retargeter", "fitters": "fitter", "identity": "identity"}

DEFAULTS = {"identity": "facegeom"}
"""The method :func:`create` builds when no name is given, per kind (only where one method is the obvious choice)."""

PRESETS: dict[str, dict[str, tuple[str, dict]]] = {
    "fitters": {"sem+": ("sem", {"clamp": True, "stop": "ric"})},
}
"""Named presets per kind: ``name -> (registered method, parameters)``; usable wherever a method name is
(``facegeom fit -m sem+``), listed by :func:`available`; parameters given with the name override the preset's."""

__all__ = ["KINDS", "DEFAULTS", "PRESETS", "available", "get", "create", "MethodSpec", "parse_value", "parse_method",
           "parse_methods", "LINEUPS"]


def _kind(kind: str) -> str:
    """The kind as in :data:`KINDS` (``"deformer"`` -> ``"deformers"``); an unknown one is an InputError naming them."""
    if isinstance(kind, str) and kind in KINDS:
        return kind
    plural = {v: k for k, v in _SINGULAR.items()}
    if isinstance(kind, str) and kind in plural:
        return plural[kind]
    raise InputError(f"unknown method kind {kind!r}; choose one of {', '.join(_SINGULAR[k] for k in KINDS)} "
                     f"(or the plural: {', '.join(k for k in KINDS if _SINGULAR[k] != k)})")


def _one(kind: str) -> str:
    """What one method of ``kind`` is called in messages (``"fitters"`` -> ``"fitter"``)."""
    return _SINGULAR[_kind(kind)]


def _group(kind: str) -> str:
    return f"facegeom.{_kind(kind)}"


def available(kind: str) -> dict[str, str]:
    """Map plugin name -> ``module:Class`` for every plugin of ``kind``, and preset name -> ``name:k=v,...``
    (:data:`PRESETS`), sorted by name."""
    eps = entry_points(group=_group(kind))
    out = {ep.name: ep.value for ep in eps}
    for name, (base, params) in PRESETS.get(_kind(kind), {}).items():
        if base in out:
            out[name] = f"{base}:" + ",".join(f"{k}={str(v).lower() if isinstance(v, bool) else v}"
                                            for k, v in params.items())
    return dict(sorted(out.items()))


def _preset(kind: str, name, params: dict):
    """``(registered name, parameters)`` of ``name``: a preset's method with its parameters under ``params``."""
    hit = PRESETS.get(_kind(kind), {}).get(name) if isinstance(name, str) else None
    if hit is None:
        return name, params
    return hit[0], {**hit[1], **params}


def get(kind: str, name: str) -> type:
    """Load and return the class registered as ``name`` in ``kind`` (a preset's: its method's class)."""
    kind = _kind(kind)
    name, _ = _preset(kind, name, {})
    eps = {ep.name: ep for ep in entry_points(group=_group(kind))}
    if name not in eps:
        names = ", ".join(sorted(eps)) or "none installed"
        raise InputError(f"no {_one(kind)} named {name!r}; available: {names}")
    return eps[name].load()


def create(kind: str, name: str | None = None, **params):
    """Build the method ``name`` of ``kind`` with constructor ``params``.

    ``kind`` is ``"deformers"``, ``"retargeters"`` or ``"fitters"`` (or the singular), or
    ``"identity"``; ``name`` a registered plugin name (:func:`available`), optional where the
    kind has a default (:data:`DEFAULTS`: ``create("identity")`` is an
    :class:`~facegeom.methods.identity.IdentityFitter`). An unknown kind or name is an
    :class:`InputError` that lists the known ones.

    An unknown parameter name (for a :class:`~facegeom.interfaces.Params`
    method: not in its ``param_names()``) is an :class:`InputError` listing the
    valid ones; the constructor checks the values (an InputError naming the parameter).
    """
    kind = _kind(kind)
    if name is None:
        if kind not in DEFAULTS:
            raise InputError(f"which {_one(kind)}? name one: {', '.join(available(kind)) or 'none installed'}")
        name = DEFAULTS[kind]
    shown = name
    name, params = _preset(kind, name, params)
    cls = get(kind, name)
    valid = cls.param_names() if hasattr(cls, "param_names") else None
    unknown = [k for k in params if valid is not None and k not in valid]
    if unknown:
        raise InputError(f"{_one(kind)} {shown!r} has no parameter {unknown[0]!r}; valid parameters: "
                         f"{', '.join(valid) or 'none'}")
    try:
        return cls(**params)
    except TypeError as exc:  # unknown keyword
        raise InputError(f"{_one(kind)} {shown!r}: {exc}") from None


@dataclass(frozen=True)
class MethodSpec:
    """A method with its parameters: ``label=name:key=value,key=value`` (label and parameters optional).

    Attributes
    ----------
    label : str
        The name shown in tables and plots (the whole spec text when no label is given).
    name : str
        The registered plugin name.
    params : dict
        Constructor parameters of the plugin.
    """

    label: str
    name: str
    params: dict = field(default_factory=dict)

    def build(self, kind: str):
        """Build the method: ``create(kind, name, **params)``.

        Parameters
        ----------
        kind : str
            One of :data:`KINDS`.

        Returns
        -------
        object
            A new instance of the registered class.
        """
        return create(kind, self.name, **self.params)


def parse_value(text: str):
    """A parameter value from text: ``None``/``null``, ``true``/``false``, an int, a float, else the string.

    Parameters
    ----------
    text : str
        The value as written (surrounding spaces ignored). Lowercase ``none``
        stays a word (e.g. ``align=none``).

    Returns
    -------
    None, bool, int, float or str
    """
    t = text.strip()
    low = t.lower()
    if t in ("None", "null"):  # lowercase "none" stays a word (e.g. align=none)
        return None
    if low in ("true", "false"):
        return low == "true"
    for cast in (int, float):
        try:
            return cast(t)
        except ValueError:
            pass
    return t


def parse_method(spec: str) -> MethodSpec:
    """Parse ``[label=]name[:k=v,k=v]``; e.g. ``tangent-paper=tangent:d=3,rings=1``.

    Parameters
    ----------
    spec : str
        The spec text; values are read with :func:`parse_value`.

    Returns
    -------
    MethodSpec
        The name is not checked against the registry (see :func:`parse_methods`).

    Raises
    ------
    InputError
        A parameter without ``=``.
    """
    spec = spec.strip()
    label = None
    head, _, params = spec.partition(":")
    if "=" in head:
        label, head = head.split("=", 1)
    kv = {}
    if params:
        for item in params.split(","):
            if "=" not in item:
                raise InputError(f"bad method spec {spec!r}: parameter {item!r} needs key=value")
            k, v = item.split("=", 1)
            kv[k.strip()] = parse_value(v)
    return MethodSpec(label or spec, head.strip(), kv)


def parse_methods(text: str, kind: str, defaults: list[str]) -> list[MethodSpec]:
    """Parse ``;``-separated specs (``,`` separates parameters); ``all`` means ``defaults``.

    Parameters
    ----------
    text : str
        ``all`` or specs such as ``rbf;t1=tangent:rings=1``.
    kind : str
        One of :data:`KINDS`; every name must be registered in it.
    defaults : list of str
        The specs that ``all`` stands for.

    Returns
    -------
    list of MethodSpec

    Raises
    ------
    InputError
        A malformed spec or a name not registered in ``kind``.
    """
    kind = _kind(kind)
    specs = [parse_method(s) for s in (defaults if text == "all" else text.split(";")) if s.strip()]
    known = available(kind)
    for s in specs:
        if s.name not in known:
            raise InputError(f"no {_one(kind)} named {s.name!r}; available: {', '.join(known)}")
    return specs


LINEUPS: dict[str, list[str]] = {
    "drive": [
        "markers-only",
        "rbf",
        "laplacian",
        "laplacian-plain=laplacian:mode=plain",
        "arap",
        "biharmonic",
        "tangent-paper=tangent:d=3,rings=1,field=position,align=none,smoothness=0,beta=None",
        "tangent-rigid=tangent:smoothness=1,align=rigid,beta=None",
        "tangent-exact=tangent:beta=None",
        "tangent",
    ],
    "scaling": [
        "tangent",
        "biharmonic",
        "arap",
    ],
    "retarget": [
        "copy",
        "rbf",
        "rbf-frame=rbf:strategy=frame",
        "laplacian",
        "tangent-paper=tangent:strategy=marker,window=2,d=1,field=position,smoothness=0,beta=None,ridge=0.0001,"
        "source_smoothing=0",
        "tangent-exact=tangent:beta=None,ridge=0.0001,source_smoothing=0",
        "tangent",
    ],
    "noise": [
        "copy",
        "rbf",
        "laplacian",
        "tangent-exact=tangent:beta=None,ridge=0.0001,source_smoothing=0",
        "tangent",
    ],
    "animate": [
        "copy",
        "rbf",
        "tangent",
    ],
    "fit": [
        "sem",
        "sem-ls",
        "sem+=sem:clamp=true,stop=ric",
        "l1reg",
        "l2reg",
        "pcaexp",
        "pcadel",
        "eos",
    ],
}
"""The method specs that ``all`` stands for in each comparison (``facegeom bench ...`` and the viewer).

Keys are the benchmark protocols; values are specs for :func:`parse_methods`.
"""
