"""An SDF's <include>s: the local file each names (a path, file://, or package:// or model:// of a known package), as
SDFormat would resolve it, for the checks that read included files before Drake does (robots.description)."""
from __future__ import annotations

import os
import pathlib

from stdm_drake.robots.xml_file import ASCII_SPACE, check_xml, parse


MAX_INCLUDE_DEPTH = 8   # SDF <include>s followed from one file (a file that includes itself stops here)


def included_files(root, path: pathlib.Path, packages: dict | None = None, includes=None) -> list[pathlib.Path]:
    """The local files the <include>s of an SDF's tree `root` (read from `path`; `includes`: these <include>
    elements only) name, as `include_target` finds them; the others are Drake's to resolve, not read here."""
    found = [include_target(include, path, packages)
             for include in (root.iter("include") if includes is None else includes)]
    return [target for target in found if target is not None]


def include_target(include, path: pathlib.Path, packages: dict | None = None) -> pathlib.Path | None:
    """The local file an SDF <include> element (of the file at `path`) names: a relative path, a file:// URI or a
    package:// or model:// URI of one of `packages` (name -> folder: the robot config's package_paths), of an SDF
    file or of a model folder (its model.config's first <sdf> file); None for another URI (another package, a web
    address) or a file that is not there."""
    uri = (include.findtext("uri") or "").strip(ASCII_SPACE)
    scheme = next((scheme for scheme in ("package://", "model://") if uri.startswith(scheme)), None)
    package, _, rest = uri.removeprefix(scheme or "").partition("/")
    if scheme is not None and package in (packages or {}):   # (Drake reads model://NAME as package://NAME)
        uri = str(pathlib.Path(packages[package]) / rest)
    if not uri or ("://" in uri and not uri.startswith("file://")):
        return None
    target = pathlib.Path(uri.removeprefix("file://"))
    # (as SDFormat joins it: `./sub/../arm.sdf` is arm.sdf, whether or not a folder `sub` exists)
    target = pathlib.Path(os.path.normpath(target if target.is_absolute() else pathlib.Path(path).parent / target))
    if target.is_dir() and (config := target / "model.config").is_file():
        check_xml(config, "a model.config is")
        name = (parse(config).getroot().findtext("sdf") or "").strip(ASCII_SPACE)
        target = target / name if name else target
    return target if target.is_file() else None
