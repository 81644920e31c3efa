"""The built-in channel maps (the TOML files of this package) and loading a map by name,
path or object; a plain map's TOML written from flight data."""

from __future__ import annotations

import tomllib
from collections.abc import Sequence
from importlib import resources
from pathlib import Path

from pipeline.errors import FsidError
from pipeline.ingest.maps.rules import ChannelMap, parse_map

#: reader format -> the built-in map used when none is given
BUILTIN = {
    "dataflash": "ardupilot_bin",
    "tlog": "mavlink_tlog",
    "ulog": "px4_ulog",
    "mcap": "fsid_mcap",
    "mcap-ros2": "ros2",
    "csv": "canonical_csv",
}


def builtin_names() -> list[str]:
    """Names of the built-in maps (the TOML files shipped in this package)."""
    return sorted(p.name[:-5] for p in resources.files(__package__).iterdir() if p.name.endswith(".toml"))


def load_map(spec: str | Path | ChannelMap | None, fmt: str | None = None, _chain: tuple[str, ...] = ()) -> ChannelMap:
    """Load a map: a built-in name, a TOML path, a ChannelMap, or None (built-in for ``fmt``).

    A user map with ``extends = "<builtin>"`` (or, for a known format, no ``extends`` and
    ``[map] override = true``) is merged over the built-in map; a map that extends itself,
    directly or through others, is an FsidError naming the chain.
    """
    if isinstance(spec, ChannelMap):
        return spec
    if spec is not None:
        if str(spec) in _chain:
            raise FsidError(
                f"channel map {_chain[0]} extends itself ({' -> '.join((*_chain, str(spec)))}): "
                "give extends a built-in map"
            )
        _chain = (*_chain, str(spec))
    if spec is None:
        if fmt is None or fmt not in BUILTIN:
            raise FsidError(f"no built-in channel map for format '{fmt}'; pass --map FILE.toml")
        return load_map(BUILTIN[fmt])
    s = str(spec)
    if s in builtin_names():
        text = resources.files(__package__).joinpath(f"{s}.toml").read_text(encoding="utf-8")
        doc = tomllib.loads(text)
        own = parse_map(doc, f"built-in map {s}")
        base = doc.get("map", {}).get("extends")
        if base:
            merged = load_map(base, fmt, _chain).merged(own)
            merged.name = own.name
            return merged
        return own
    path = Path(s)
    if not path.is_file():
        raise FsidError(f"channel map '{s}' not found: give a TOML file or one of {', '.join(builtin_names())}")
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise FsidError(f"channel map {path}: not valid TOML ({exc}); fix the file") from None
    user = parse_map(doc, str(path))
    base = doc.get("map", {}).get("extends")
    if base is None and doc.get("map", {}).get("override") and fmt in BUILTIN:
        base = BUILTIN[fmt]
    if base:
        return load_map(base, fmt, _chain).merged(user)
    return user


def plain_map_toml(fd, name: str, formats: Sequence[str], drop: Sequence[str] = ()) -> str:
    """The TOML of a map that reads ``fd``'s channels straight from the sources they came
    from (one plain source each, in the channel's SI unit), without those in ``drop``: for
    channels a reader fills by name (the product's own MCAP), e.g. the same log without its
    vanes. Transforms, PWM and scale rules are not reproduced: use it on plain sources."""
    lines = ["[map]", f'name = "{name}"', f"formats = {list(formats)!r}".replace("'", '"'), ""]
    for k in fd.names:
        if k not in drop:
            lines += [f"[channels.{k}]", f'source = ["{fd[k].source}"]', f'unit = "{fd[k].unit}"', ""]
    return "\n".join(lines)
