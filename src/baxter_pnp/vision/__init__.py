"""The thesis colour pipeline (section 3.2, Algorithm 1): BGR image in -> polygon vertices out. No ROS.

Default stages, every parameter in ``config/vision.yaml`` (``config.VisionConfig``):

1. BGR -> HSV (``cv2.cvtColor``).
2. Gamma correction ``S_out = 255 (S_in / 255) ** gamma`` with gamma = 0.6 (eq. 3.13), as a LUT.
3. Dynamic saturation threshold ``(S_max - S_min) / epsilon`` with epsilon = 2.25 (eq. 3.14).
4. Over-saturation: S = 250, V = 180 where the corrected S is at or above the threshold, S = V = 0 below.
5. Low-pass filter with the kernel of eq. 3.17, ``(1/(2+b)^2) [1 b 1]^T [1 b 1]``, b = 2 (separable).
6. Colour range (green: H 50-70, S 100-255, V 100-255 on OpenCV's 0-179 hue scale) -> binary mask
   (on the over-saturated image, as in the thesis).
7. Morphological opening, then closing.
8. Laplacian sharpening (kernel ``[-1 -1 -1; -1 8 -1; -1 -1 -1]``), then ``findContours``.
9. Area threshold; Douglas-Peucker (``approxPolyDP``); merge of vertices closer than a distance
   (the thesis's "high pass filter" of chapter 6); shape from the vertex count.

Modules, by stage: ``config`` (parameters), ``colour`` (steps 1-8), ``topface`` (top-face isolation),
``polygon`` (step 9, cut corners, side fitting), ``subpixel`` (sub-pixel vertices), ``detection`` (the
stages composed: ``detect``, ``select_target``, ``draw_detections``). Their public names are re-exported here.

Where this departs from the letter of Algorithm 1, and why:

- Gamma is applied to S only. Algorithm 1 also raises H and V to the power gamma, but hue is an angle
  (a power law moves the colour ranges of step 6 and breaks the red wrap-around), and V is overwritten
  by the over-saturation of step 4 anyway, so its correction has no effect on the output.
- The low-pass filter is applied to S and V, not H: averaging hues across an edge, or across the red
  0/179 wrap-around, makes up hues that are in no range.
- Eq. 3.17 as transcribed shows a 4-element column ``[1 b b 1]``; its normalisation ``1/(2+b)^2`` only
  makes sense for ``[1 b 1]^T [1 b 1]``, which is what is used (it sums to 1).
- The merge distance is a fraction of the polygon's perimeter, not a pixel count: the thesis notes that
  its fixed-distance filter lowered the height at which a (smaller-looking) square was still found.

Beyond the thesis (all switchable in the YAML):

- Cut corners (``remove_cut_corners``, after the merge): morphology rounds acute corners and a side
  face can clip one, and Douglas-Peucker then keeps both ends of the cut; an edge whose neighbours,
  extended, meet in a point adding less than ``cut_corner_area_fraction`` of the area is replaced by
  that point (a true corner adds 8 % or more even in strong perspective). 0 disables it.
- Flat vertices (``remove_flat_vertices``, after the cut corners): a vertex whose triangle with its
  neighbours is less than ``flat_vertex_area_fraction`` (8 %) of the area is a bend in a side (the outline
  following a side-face sliver or a grid line along part of it) and is dropped; a regular polygon's true
  corner is a sixth of its area or more. 0 disables it.
- Top-face isolation (``isolate_top_face``): in oblique views the side faces (same hue, darker) join
  the blob and turn a square into a hexagon. Under light from above the table the top face is the
  brightest face: V of the original image, inside the blob, is split by Otsu's threshold (repeated
  while the split is significant, for a side face nearly as bright as the top), and the brightest
  region that is as saturated as the top (not the pale mix of a side face and the table) is kept.
  A side face lit within ``min_contrast`` (12 %) of the top, or brighter (a low light), is not split off.
- Coarse corners (``fit_polygon_sides``): lines fitted to the sides of the outline, away from the
  corners that morphology and the face split round off, intersected.
- Shape from the outline's harmonics (``shape_harmonics``, ``harmonic_shape``, polygons up to 40 px): the
  outline, whitened by its second moments (an affine view of a regular polygon becomes a regular one), as a
  radius against the angle; its strongest harmonic of 3-6 (amplitude times order, undoing blur's damping) is the
  vertex count where it beats the runner-up twice over and the corner rules counted otherwise (a 15-25 px
  pentagon's blunt corners made a square), the hull then reduced to that many vertices (``hull_polygon``); at half a
  sharp polygon's amplitude they also overrule the disc test (a blurred 20 px hexagon fits an ellipse as well).
- Side faces as bright as the top (``cut_side_faces``, polygons of 40 px and more): an edge with a crease
  inside it, a straight step of V nearly parallel to it all along it, the strip before it evenly darker than
  the face beyond, is moved onto the crease (docs/perception.md, "Side faces as bright as the top").
- A weaker chroma floor (``chroma.weak_*``): for the blobs where a colour's floor found nothing good (the
  candidate search saw more blobs of the colour in a region than it has good detections), blobs at 0.7 of the floor
  count when they stand out from their surroundings along the colour's hue and make good polygons (a dim die on a
  dark table, a dim cube beside a bright one; docs/perception.md, "Dim faces").
- Islands of colour (``chroma.surround_*``, ``stands_out``): a polygon must stand out from a ring 3-6 px around
  it along its hue, and its colour may fill at most 70 % of that ring (a fragment of a larger coloured area, a
  button's cap, a tinted print, a glow, is no block); a polygon narrower than ``min_aspect`` is a sliver; white-
  balanced highlights clipped in one channel stay grey (docs/perception.md, "Fragments of larger coloured areas").
- Sub-pixel vertices (``refine_vertices``): each edge is re-measured on the original image along its
  normal and a line is fitted to the edge points (Huber), consecutive lines intersected. The edge
  point of a profile comes from a two-colour model, top face and table: the table's share locates the
  table's edge, and the darkening no mix of the two explains measures the side face in between: one
  thinner than the blur (1-3 px, near face-on views off-centre) is removed by its darkening mass, a
  wider one by the step to its colour. A polygon cut by the image border is kept only with an edge of its own
  along a straight image edge (``border_edge_max_rms_px``; docs/perception.md, "Border-cut fragments").
- A floor under the dynamic threshold (``min_saturation_threshold``) and a zero border for the
  Laplacian, so a colourless image stays empty and a blob cut by the image border keeps a closed outline.
- Speed (``roi``): the candidate blobs of each colour are found by the same stages on a subsampled
  image; the full pipeline then runs only in padded regions around them, for their colours. The
  dynamic threshold (eq. 3.14) and the white balance are taken from the subsampled image, with the ROI search
  on or off (so both give the same result).

Pixels are (u, v) = (column, row), origin at the centre of the top-left pixel; vertex coordinates are
in the raw (distorted) image.
"""
from baxter_pnp.vision.colour import (LAPLACIAN_KERNEL, colour_mask, find_blobs, gamma_lut, laplacian_sharpen,
                                      lowpass, lowpass_kernel, lowpass_kernel_1d, open_close, oversaturate,
                                      saturation_threshold)
from baxter_pnp.vision.config import (DEFAULT_VISION_YAML, HarmonicShapeConfig, RoiConfig, SideFaceConfig,
                                      SubpixelConfig, TopFaceConfig, VisionConfig)
from baxter_pnp.vision.detection import (Detection, blob_detection, detect, draw_detections, select_target,
                                         validate_image)
from baxter_pnp.vision.polygon import (SHAPE_OF_VERTEX_COUNT, approximate_polygon, classify_shape, fit_polygon_sides,
                                       hull_polygon, merge_close_vertices, order_vertices, remove_cut_corners,
                                       remove_flat_vertices, shape_harmonics)
from baxter_pnp.vision.sideface import cut_side_faces
from baxter_pnp.vision.subpixel import refine_vertices
from baxter_pnp.vision.topface import isolate_top_face

__all__ = ['DEFAULT_VISION_YAML', 'LAPLACIAN_KERNEL', 'SHAPE_OF_VERTEX_COUNT', 'Detection', 'HarmonicShapeConfig',
           'RoiConfig', 'SideFaceConfig', 'SubpixelConfig', 'TopFaceConfig', 'blob_detection', 'VisionConfig',
           'approximate_polygon', 'classify_shape', 'colour_mask', 'cut_side_faces', 'detect', 'draw_detections',
           'find_blobs', 'fit_polygon_sides', 'gamma_lut', 'hull_polygon', 'isolate_top_face', 'laplacian_sharpen',
           'lowpass', 'lowpass_kernel', 'lowpass_kernel_1d', 'merge_close_vertices', 'open_close', 'order_vertices',
           'oversaturate', 'refine_vertices', 'remove_cut_corners', 'remove_flat_vertices', 'saturation_threshold',
           'select_target', 'shape_harmonics', 'validate_image']
