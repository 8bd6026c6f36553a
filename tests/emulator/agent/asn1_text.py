"""ASN.1 text of a type pycrate has compiled, for another compiler to read (asn1tools, in the J2735 tests).

pycrate ships ISO TS 19091's DSRC module compiled to Python (``pycrate_asn1dir/ITS_IS.py``), not its ASN.1 text,
and asn1tools carries no DSRC module. The tests' second, independent decoder needs text: this writes it back from
the compiled objects, with what an unaligned PER encoding depends on (the components and their order, OPTIONAL
and DEFAULT, the extension markers and additions, value and size constraints, the enumerations' values), each
type written in line. A DEFAULT is written OPTIONAL (UPER encodes both as a presence bit); an open type as an
OCTET STRING (X.691 encodes an open type as an unconstrained octet string). What it writes for SPAT was checked
against the module's text in pycrate's repository (``pycrate_asn1dir/ETSI_ITS_IS_TS103301/DSRC.asn``).
"""

from __future__ import annotations

from typing import Any


def _constraint(const: Any) -> str:
    """A value or size constraint: its root values and ranges, extensible or not ('' for none)."""
    if const is None or not const.root:
        return ""
    parts = []
    for r in const.root:
        if hasattr(r, "lb"):
            parts.append(f"{'MIN' if r.lb is None else r.lb}..{'MAX' if r.ub is None else r.ub}")
        else:
            parts.append(str(r))
    return f"({' | '.join(parts)}{', ...' if const.ext is not None else ''})"


def _size(o: Any) -> str:
    inner = _constraint(getattr(o, "_const_sz", None))
    return f" (SIZE{inner})" if inner else ""


def _items(o: Any, render: Any) -> str:
    """A SEQUENCE's, CHOICE's or ENUMERATED's items: the root, then the extension marker and additions."""
    items = [render(name) for name in o._root]
    if o._ext is not None:
        items += ["...", *(render(name) for name in o._ext)]
    return "{ " + ", ".join(items) + " }"


def text(o: Any) -> str:
    """The ASN.1 notation of pycrate object ``o``."""
    t = o.TYPE
    if t == "INTEGER":
        return f"INTEGER {_constraint(o._const_val)}".rstrip()
    if t in ("BOOLEAN", "NULL"):
        return t
    if t in ("IA5String", "OCTET STRING", "BIT STRING"):
        return t + _size(o)
    if t == "OPEN_TYPE":
        return "OCTET STRING"
    if t == "ENUMERATED":
        return "ENUMERATED " + _items(o, lambda name: f"{name}({o._cont[name]})")
    if t == "SEQUENCE":
        def component(name: str) -> str:
            c = o._cont[name]
            return f"{name} {text(c)}{' OPTIONAL' if c._opt or c._def is not None else ''}"
        return "SEQUENCE " + _items(o, component)
    if t == "CHOICE":
        return "CHOICE " + _items(o, lambda name: f"{name} {text(o._cont[name])}")
    if t == "SEQUENCE OF":
        return f"SEQUENCE{_size(o)} OF {text(o._cont)}"
    raise ValueError(f"{o._name}: no ASN.1 text written for {t}")


def module(name: str, types: dict[str, Any]) -> str:
    """A module of these types for asn1tools to compile."""
    body = "\n".join(f"{n} ::= {text(o)}" for n, o in types.items())
    return f"{name} DEFINITIONS AUTOMATIC TAGS ::= BEGIN\n{body}\nEND\n"
