"""Parameters of the vision pipeline (``config/vision.yaml``): lengths in pixels of the full-resolution image;
the thesis's colour ranges in OpenCV's HSV (hue 0-179, saturation and value 0-255), the chroma pipeline's colour
classes in CIELAB (L* 0-100, chroma in a*b* units, hue angle in degrees)."""
import os
from dataclasses import dataclass, field
from typing import Dict

from baxter_pnp.params import ParameterError, Parameters
from baxter_pnp.runtime import PACKAGE_ROOT

DEFAULT_VISION_YAML = os.path.join(PACKAGE_ROOT, 'config', 'vision.yaml')
_HSV_TOP = (179, 255, 255)


@dataclass(frozen=True)
class TopFaceConfig(Parameters):
    """Top-face isolation: the brightest face (by V) inside the blob (see ``topface.isolate_top_face``).

    ``min_contrast``: fraction of the bright class's mean V; ``min_face_fraction``: fraction of the blob's
    interior pixels; ``min_solidity``: area / convex-hull area of the face."""
    enabled: bool = True
    min_contrast: float = 0.12
    min_face_fraction: float = 0.1
    min_solidity: float = 0.8


@dataclass(frozen=True)
class RoiConfig(Parameters):
    """Candidate search on an image subsampled by ``downsample``; full pipeline in padded regions."""
    enabled: bool = True
    downsample: int = 8
    padding_px: int = 16

    def validate(self):
        self.require(self.downsample >= 1, 'downsample', 'must be >= 1')


@dataclass(frozen=True)
class SubpixelConfig(Parameters):
    """Sub-pixel edge-line refinement of the vertices (see ``subpixel.refine_vertices``).

    Lengths (``*_px``) in pixels of the full image; ``min_contrast`` a BGR distance (0-255 per channel);
    ``side_face_darkening`` 1 - (side face / top face brightness)."""
    enabled: bool = True
    passes: int = 1
    profile_half_length_px: float = 4.0
    profile_step_px: float = 0.5
    profiles_per_edge: int = 16
    corner_margin_px: float = 1.5
    min_edge_length_px: float = 4.0
    min_points: int = 6
    min_contrast: float = 20.0
    side_face_darkening: float = 0.5
    min_strip_mass_px: float = 0.15
    resolved_strip_px: float = 2.5
    max_rms_px: float = 0.5
    max_shift_px: float = 5.0

    def validate(self):
        self.require(self.passes >= 1, 'passes', 'must be >= 1 (enabled: false turns the refinement off)')
        self.require(self.profiles_per_edge >= 2, 'profiles_per_edge', 'must be >= 2')
        self.require(self.profile_step_px > 0.0, 'profile_step_px', 'must be > 0')
        self.require(self.max_rms_px > 0.0, 'max_rms_px', 'must be > 0')


@dataclass(frozen=True)
class SideFaceConfig(Parameters):
    """Side-face strips cut off along their crease (see ``sideface.cut_side_faces``): polygons of at least
    ``min_size_px`` (square root of the area), creases up to ``max_depth_fraction`` of that inside an edge, a rise
    of V across them of at least ``min_rise`` of the face's, in at least ``min_agreement`` of the profiles, the strip
    at most ``max_strip_brightness`` of the face's V."""
    enabled: bool = True
    min_size_px: float = 40.0
    max_depth_fraction: float = 0.35
    min_rise: float = 0.04
    min_agreement: float = 0.95
    max_strip_brightness: float = 0.96

    def validate(self):
        self.require(self.min_size_px >= 0.0, 'min_size_px', 'must be >= 0')
        self.require(0.0 < self.max_depth_fraction < 0.5, 'max_depth_fraction', 'must be in (0, 0.5)')
        self.require(self.min_rise > 0.0, 'min_rise', 'must be > 0')
        self.require(0.0 < self.min_agreement <= 1.0, 'min_agreement', 'must be in (0, 1]')
        self.require(0.0 < self.max_strip_brightness < 1.0, 'max_strip_brightness', 'must be in (0, 1)')


@dataclass(frozen=True)
class HarmonicShapeConfig(Parameters):
    """A small polygon's shape from its outline's harmonics (see ``polygon.shape_harmonics``): on polygons up to
    ``max_size_px`` (square root of the hull's area), the harmonics' vertex count replaces the corner rules' where
    its amplitude is at least ``min_margin`` times the runner-up's, and an outline the disc test calls round is a
    polygon when that amplitude is also ``min_strength`` of a sharp regular polygon's."""
    enabled: bool = True
    max_size_px: float = 40.0
    min_margin: float = 2.0
    min_strength: float = 0.5

    def validate(self):
        self.require(self.max_size_px >= 0.0, 'max_size_px', 'must be >= 0')
        self.require(self.min_margin > 1.0, 'min_margin', 'must be > 1')
        self.require(self.min_strength > 0.0, 'min_strength', 'must be > 0')


PIPELINES = ('chroma', 'thesis')


@dataclass(frozen=True)
class ColourClass(Parameters):
    """A colour of the chroma pipeline: CIELAB hue angle within ``hue_deg`` +- ``hue_half_width_deg`` (deg),
    chroma at least ``min_chroma``, lightness L* at least ``min_lightness`` (0-100)."""
    hue_deg: float
    hue_half_width_deg: float
    min_chroma: float = 20.0
    min_lightness: float = 8.0

    def validate(self):
        self.require(0.0 < self.hue_half_width_deg <= 90.0, 'hue_half_width_deg', 'must be in (0, 90] deg')
        self.require(self.min_chroma >= 5.0, 'min_chroma',
                     'must be >= 5 (below that, grey and black pixels are a colour)')
        self.require(0.0 <= self.min_lightness < 100.0, 'min_lightness', 'must be in [0, 100)')


@dataclass(frozen=True)
class ChromaConfig(Parameters):
    """The chroma pipeline (``vision.chroma``): white balance from the image (gains clipped to ``max_gain``),
    the colour ``classes``, and ``min_fill``: the least fraction of a detected polygon its colour covers
    (a die's pips leave most of its face; a yellow box with a red button in it does not); ``max_residual_cast``:
    the chroma of a cast the white balance could not remove (``chroma.white_balance``) beyond which every class's
    chroma floor is raised by the excess; ``weak_*``: a second, weaker floor for faces too dim for a class's own,
    trusted only on a balanced image, for blobs that stand out from their surroundings and make good polygons
    (``detection._with_weak_detections``); ``surround_*``: every polygon stands out from a ring 3-6 px around it,
    its median chroma along its class's hue above the ring's by ``surround_min_contrast`` of the class's floor, and
    at most ``surround_max_share`` of the ring has ``surround_share_floor`` of the floor (``detection.stands_out``):
    a block is an island of colour on the table, a fragment of a larger coloured area (a button's cap, a tinted
    print, a glow) is not."""
    white_balance: bool = True
    max_gain: float = 2.0
    max_residual_cast: float = 5.0
    min_fill: float = 0.7
    weak_floor_fraction: float = 0.7
    weak_min_contrast: float = 16.0
    weak_min_quality: float = 0.3
    surround_min_contrast: float = 0.5
    surround_max_share: float = 0.7
    surround_share_floor: float = 0.3
    classes: Dict[str, ColourClass] = field(default_factory=lambda: {'green': ColourClass(150.0, 40.0, 19.0)})

    def validate(self):
        self.require(self.max_gain >= 1.0, 'max_gain', 'must be >= 1')
        self.require(0.0 <= self.min_fill <= 1.0, 'min_fill', 'must be in [0, 1]')
        self.require(self.max_residual_cast >= 0.0, 'max_residual_cast', 'must be >= 0')
        self.require(0.0 < self.weak_floor_fraction <= 1.0, 'weak_floor_fraction', 'must be in (0, 1] (1 = off)')
        self.require(self.weak_min_contrast >= 0.0, 'weak_min_contrast', 'must be >= 0')
        self.require(0.0 <= self.weak_min_quality <= 1.0, 'weak_min_quality', 'must be in [0, 1]')
        self.require(self.surround_min_contrast >= 0.0, 'surround_min_contrast', 'must be >= 0 (0 = off)')
        self.require(0.0 < self.surround_max_share <= 1.0, 'surround_max_share', 'must be in (0, 1] (1 = off)')
        self.require(0.0 < self.surround_share_floor <= 1.0, 'surround_share_floor', 'must be in (0, 1]')
        self.require(bool(self.classes), 'classes', 'must define at least one colour')


@dataclass(frozen=True)
class VisionConfig(Parameters):
    """Parameters of the pipeline; the fields mirror ``config/vision.yaml`` (see its comments).

    ``pipeline``: the colour stage, ``chroma`` (``chroma.classes``) or ``thesis`` (the thesis's over-saturation
    and ``colours``). ``colours`` maps a colour name to a tuple of inclusive HSV ranges ``((h, s, v) low,
    (h, s, v) high)`` whose masks are OR-ed (red needs two: its hue wraps around 0); given as YAML lists,
    parsed on construction.
    """
    pipeline: str = 'chroma'
    chroma: ChromaConfig = field(default_factory=ChromaConfig)
    gamma: float = 0.6
    saturation_epsilon: float = 2.25
    min_saturation_threshold: float = 30.0
    oversaturated_s: int = 250
    oversaturated_v: int = 180
    lowpass_b: float = 2.0
    colours: dict = field(default_factory=lambda: {'green': (((50, 100, 100), (70, 255, 255)),)})
    morphology_kernel_px: int = 3
    laplacian_sharpening: bool = True
    min_area_px: float = 100.0
    min_triangle_area_px: float = 100.0
    min_triangle_quality: float = 0.0
    approx_epsilon_fraction: float = 0.02
    merge_distance_fraction: float = 0.05
    cut_corner_area_fraction: float = 0.04
    cut_corner_clear_area_fraction: float = 0.04
    cut_corner_clear_max_size_px: float = 100.0
    flat_vertex_area_fraction: float = 0.05
    border_margin_px: float = 3.0
    border_edge_max_rms_px: float = 1.0
    min_aspect: float = 0.2
    top_face: TopFaceConfig = field(default_factory=TopFaceConfig)
    side_face_cut: SideFaceConfig = field(default_factory=SideFaceConfig)
    harmonic_shape: HarmonicShapeConfig = field(default_factory=HarmonicShapeConfig)
    subpixel: SubpixelConfig = field(default_factory=SubpixelConfig)
    roi: RoiConfig = field(default_factory=RoiConfig)

    def __post_init__(self):
        object.__setattr__(self, 'colours', {name: _parse_colour_ranges(name, ranges)
                                             for name, ranges in self.colours.items()})

    def validate(self):
        self.require(self.gamma > 0, 'gamma', 'must be > 0')
        self.require(self.saturation_epsilon > 0, 'saturation_epsilon', 'must be > 0')
        self.require(self.lowpass_b >= 0, 'lowpass_b', 'must be >= 0')
        self.require(self.morphology_kernel_px >= 1, 'morphology_kernel_px', 'must be >= 1')
        self.require(self.min_triangle_area_px > 0.0, 'min_triangle_area_px', 'must be > 0')
        self.require(0.0 <= self.min_triangle_quality <= 1.0, 'min_triangle_quality', 'must be in [0, 1]')
        self.require(self.cut_corner_clear_area_fraction >= self.cut_corner_area_fraction,
                     'cut_corner_clear_area_fraction', 'must be >= cut_corner_area_fraction')
        self.require(self.cut_corner_clear_max_size_px >= 0, 'cut_corner_clear_max_size_px', 'must be >= 0')
        self.require(self.border_edge_max_rms_px > 0, 'border_edge_max_rms_px', 'must be > 0')
        self.require(0.0 <= self.min_aspect < 1.0, 'min_aspect', 'must be in [0, 1) (0 = off)')
        self.require(self.pipeline in PIPELINES, 'pipeline', 'must be one of %s' % ', '.join(PIPELINES))
        self.require(bool(self.colours), 'colours', 'must define at least one colour')

    @property
    def min_blob_area_px(self):
        """px^2: the smallest blob looked at (``min_area_px``, or a triangle's ``min_triangle_area_px`` if smaller)."""
        return min(self.min_area_px, self.min_triangle_area_px)

    def colour_names(self):
        """Names of the colours of the active pipeline, in YAML order."""
        return list(self.chroma.classes if self.pipeline == 'chroma' else self.colours)

    @classmethod
    def from_yaml(cls, path=None):
        """Config from a YAML file (default ``config/vision.yaml`` of the package); ParameterError naming the key."""
        return super().from_yaml(path or DEFAULT_VISION_YAML)


def _parse_colour_ranges(name, ranges):
    """Tuple of ``((h, s, v), (h, s, v))`` integer ranges, or ParameterError naming the colour (``colours.red``)."""
    key = f'colours.{name}'
    try:
        parsed = tuple((tuple(int(c) for c in low), tuple(int(c) for c in high)) for low, high in ranges)
    except (TypeError, ValueError):
        raise ParameterError(key, f'must be a list of [[h, s, v], [h, s, v]] ranges (got {ranges!r})') from None
    if not parsed:
        raise ParameterError(key, 'has no range')
    for low, high in parsed:
        if len(low) != 3 or len(high) != 3:
            raise ParameterError(key, f'each bound needs 3 values (h, s, v) (got {low}-{high})')
        if not all(0 <= lo <= hi <= top for lo, hi, top in zip(low, high, _HSV_TOP)):
            raise ParameterError(key, f'range {low}-{high} must satisfy 0 <= low <= high <= {_HSV_TOP}')
    return parsed
