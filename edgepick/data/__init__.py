"""Data sets: synthetic RGB-D scenes (`data synth`), imports from Cityscapes, BOP and CVAT, and the
native layout they are written in (docs/contracts.md#data-set-layout). No torch.

    from edgepick.data import NativeDataset, SynthConfig, synthesize
"""

from typing import TYPE_CHECKING

from edgepick.lazy import lazy_attributes

_WHERE = {
    "CityscapesClasses": "config", "ImportConfig": "config", "ImportFormat": "config", "Split": "config",
    "import_dataset": "importers", "NativeDataset": "native", "read_meta": "native", "contact_sheet": "preview",
    "CLASSES": "render", "LIGHTINGS": "render", "Layout": "render", "Placed": "shapes", "SceneRenderer": "render",
    "ObjectModel": "shapes", "SynthConfig": "synth", "synthesize": "synth"
}
__all__ = sorted(_WHERE)

if TYPE_CHECKING:
    from edgepick.data.config import CityscapesClasses, ImportConfig, ImportFormat, Split
    from edgepick.data.importers import import_dataset
    from edgepick.data.native import NativeDataset, read_meta
    from edgepick.data.preview import contact_sheet
    from edgepick.data.render import CLASSES, LIGHTINGS, Layout, SceneRenderer
    from edgepick.data.shapes import ObjectModel, Placed
    from edgepick.data.synth import SynthConfig, synthesize


__getattr__ = lazy_attributes(__name__, _WHERE)
