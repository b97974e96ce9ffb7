"""Assets by name: the one door from a scenario's strings to ``ObjectAsset``s and ``SceneLayout``s.

A name is either a catalogue entry (``data_gen.assets.library`` objects,
``data_gen.assets.layouts`` layouts) or a reference ``<scheme>:<path>?<options>``
whose scheme picks a loader from the tables below:

* objects — ``file:`` triangle meshes and ``ply:`` 3DGS splat objects
  (``data_gen.assets.imported``);
* scene layouts — ``ply:`` captured 3DGS scenes (``data_gen.assets.captured``).

Adding a source of assets is adding one row.  Nothing in ``data_gen.assets``
imports this module, so the package's imports form no cycle.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

from data_gen.assets.captured import captured_scene
from data_gen.assets.imported import imported_object
from data_gen.assets.layout_variants import list_variant_layouts, variant_layout
from data_gen.assets.layouts import layout, list_layouts
from data_gen.assets.library import library_object, list_library_objects
from data_gen.assets.object_asset import ObjectAsset
from data_gen.assets.scene_layout import SceneLayout

OBJECT_LOADERS: dict[str, Callable[[str], ObjectAsset]] = {"file": imported_object, "ply": imported_object}
LAYOUT_LOADERS: dict[str, Callable[[str], SceneLayout]] = {"ply": captured_scene}


def _scheme(name: str) -> str:
    scheme, colon, _ = name.partition(":")
    return scheme if colon else ""


def is_object_name(name: str) -> bool:
    """Whether ``name`` names an object: a library name or a reference with a known scheme (not opened)."""
    return _scheme(name) in OBJECT_LOADERS or name in list_library_objects()


def get_object(name: str, size_m: float | None = None) -> ObjectAsset:
    """The object ``name`` (library name or ``file:``/``ply:`` reference), scaled so that its largest
    extent is ``size_m`` (m) when given; an unknown name lists the valid ones."""
    if not is_object_name(name):
        raise KeyError(
            f"unknown object {name!r}; valid objects: {', '.join(list_library_objects())}, "
            f"or a reference <scheme>:<path> with scheme in {sorted(OBJECT_LOADERS)}"
        )
    loader = OBJECT_LOADERS.get(_scheme(name), library_object)
    asset = loader(name)
    return asset if size_m is None else asset.scaled_to(size_m)


def list_objects() -> list[str]:
    """Names of all library objects (core and families), sorted (references to files are not listed)."""
    return list_library_objects("all")


def object_pool(library: str) -> list[str]:
    """What a scenario with ``objects: null`` draws from: ``core`` (the 34 hand-built objects, whose draws
    earlier data and tests pin) or ``all`` (core plus the parametric families), sorted."""
    return list_library_objects(library)


def is_scene_layout_name(name: str) -> bool:
    """Whether ``name`` names a scene layout: a catalogue name or a reference with a known scheme (not opened)."""
    return _scheme(name) in LAYOUT_LOADERS or name in list_scene_layouts()


def get_scene_layout(name: str) -> SceneLayout:
    """The scene layout ``name`` (catalogue name or ``ply:`` captured scene); an unknown name lists the
    valid ones."""
    if not is_scene_layout_name(name):
        raise KeyError(
            f"unknown scene layout {name!r}; valid layouts: {', '.join(list_scene_layouts())}, "
            f"or a reference <scheme>:<path> with scheme in {sorted(LAYOUT_LOADERS)}"
        )
    if _scheme(name) in LAYOUT_LOADERS:
        return LAYOUT_LOADERS[_scheme(name)](name)
    return _catalogue_layout(name)


@functools.lru_cache(maxsize=None)
def _catalogue_layout(name: str) -> SceneLayout:
    """A catalogue layout, built once per process (layouts are immutable; scenario sampling looks them up
    once per draw)."""
    return variant_layout(name) if name in list_variant_layouts() else layout(name)


def list_scene_layouts() -> list[str]:
    """Names of the catalogue layouts: the first catalogue (``layouts``), then ``layout_variants``, each in
    catalogue order (captured scenes are not listed)."""
    return list_layouts() + list_variant_layouts()
