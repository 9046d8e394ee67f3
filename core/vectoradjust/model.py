"""In-memory description of an adjustment project: plain numpy arrays, no file I/O.

These containers are what the numerical pipeline (:mod:`vectoradjust.pipeline`)
consumes. The file readers (:mod:`vectoradjust.files.readers`), the simulator
(:mod:`vectoradjust.simulate`) and the QGIS plugin all produce them, so the same
numbers come out whichever way the data arrived.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np

__all__ = [
    "Camera",
    "ImageSpec",
    "Measurements",
    "ControlPoints",
    "LineLayer",
    "VectorSpec",
    "AdjustmentSettings",
    "ProjectData",
]


@dataclass
class Camera:
    """Interior orientation used by the collinearity equations.

    Attributes
    ----------
    focal_length : float
        Calibrated focal length (mm).
    principal_point : tuple of float
        ``x0, y0`` (mm).
    calibration : object, optional
        A full calibration (fiducials, distortion, pixel size) for image coordinate
        refinement, when the project gives one.
    """

    focal_length: float
    principal_point: tuple[float, float] = (0.0, 0.0)
    calibration: Any = None


@dataclass
class ImageSpec:
    """One image: approximate exterior orientation and its optional priors.

    Attributes
    ----------
    id : str
    position : numpy.ndarray, shape (3,)
        Approximate (or prior) exposure station XL, YL, ZL (m).
    attitude : numpy.ndarray, shape (3,)
        Approximate omega, phi, kappa in **degrees**.
    sigma_position : float, tuple of 3 floats or None
        Prior sigma of the position (m; one for X, Y, Z or per axis, e.g. GNSS 3 m
        horizontal, 5 m vertical); ``None`` = free parameter.
    sigma_attitude : float, tuple of 3 floats or None
        Prior sigma of the angles (degrees; one or per angle); ``None`` = free parameter.
    date : str or None
        Acquisition date (ISO 8601) for provenance.
    model : str
        ``"frame"`` (a frame camera: collinearity, the default) or ``"rpc"`` (a satellite
        image with rational polynomial coefficients; position and attitude unused).
    rpc : vectoradjust.sensor.models.RpcImage or None
        For ``model = "rpc"``: the RPC file, its bias model and the bias priors; its
        ``rpc`` (the coefficients) is filled when the project's files are read.
    """

    id: str
    position: np.ndarray
    attitude: np.ndarray
    sigma_position: Optional[float | tuple] = None
    sigma_attitude: Optional[float | tuple] = None
    date: Optional[str] = None
    model: str = "frame"
    rpc: Any = None


@dataclass
class Measurements:
    """Image coordinate measurements, one row per (point, image).

    Attributes
    ----------
    point_id, image_id : numpy.ndarray of str, shape (k,)
    xy : numpy.ndarray, shape (k, 2)
        Photo coordinates (mm), refined (interior orientation applied).
    sigma : numpy.ndarray, shape (k, 2)
        Standard deviations (mm).
    source : str
        File (or layer) name, for error messages.
    rows : numpy.ndarray of int, shape (k,)
        1-based line numbers in the source (header = line 1), for error messages.
    """

    point_id: np.ndarray
    image_id: np.ndarray
    xy: np.ndarray
    sigma: np.ndarray
    source: str = "<measurements>"
    rows: Optional[np.ndarray] = None

    def __post_init__(self) -> None:
        self.point_id = np.asarray(self.point_id, dtype=object).astype(str)
        self.image_id = np.asarray(self.image_id, dtype=object).astype(str)
        self.xy = np.asarray(self.xy, float).reshape(-1, 2)
        self.sigma = np.broadcast_to(np.asarray(self.sigma, float), self.xy.shape).copy()
        if self.rows is None:
            self.rows = np.arange(2, len(self.point_id) + 2)


@dataclass
class ControlPoints:
    """Surveyed ground points.

    Attributes
    ----------
    point_id : numpy.ndarray of str, shape (n,)
    xyz : numpy.ndarray, shape (n, 3)
        Surveyed coordinates in the project CRS (m).
    sigma : numpy.ndarray, shape (n, 3)
        Standard deviations (m).
    role : numpy.ndarray of str, shape (n,)
        ``"control"`` (in the adjustment) or ``"check"`` (independent check).
    cov : numpy.ndarray, shape (n, 3, 3), optional
        Full covariance where given; overrides ``sigma``.
    source : str
    rows : numpy.ndarray of int, optional
    reading : dict, optional
        How the reader brought the points into the project CRS
        (:func:`vectoradjust.files.readers.control_to_project_crs`: source CRS, the
        transformation PROJ chose and its accuracy, the vertical datums, a ``warning``);
        None when not given.
    """

    point_id: np.ndarray
    xyz: np.ndarray
    sigma: np.ndarray
    role: np.ndarray
    cov: Optional[np.ndarray] = None
    source: str = "<control>"
    rows: Optional[np.ndarray] = None
    reading: Optional[dict] = None

    def __post_init__(self) -> None:
        self.point_id = np.asarray(self.point_id, dtype=object).astype(str)
        self.xyz = np.asarray(self.xyz, float).reshape(-1, 3)
        self.sigma = np.broadcast_to(np.asarray(self.sigma, float), self.xyz.shape).copy()
        self.role = np.asarray(self.role, dtype=object).astype(str)
        if self.rows is None:
            self.rows = np.arange(2, len(self.point_id) + 2)


@dataclass
class DemGrid:
    """A DEM held in memory, in the project CRS (north-up grid).

    Attributes
    ----------
    grid : numpy.ndarray, shape (rows, cols)
        Heights.
    transform : tuple of 6 floats
        GDAL geotransform ``(x_origin, dx, 0, y_origin, 0, -dy)``.
    nodata : float or None
    """

    grid: np.ndarray
    transform: tuple
    nodata: Optional[float] = None


@dataclass
class LineLayer:
    """A road line layer flattened to vertex arrays, attributes kept verbatim.

    Attributes
    ----------
    name : str
        The database name (``[[vectors]] name``).
    feature_ids : numpy.ndarray of str, shape (nf,)
        Feature ids (the id field's values, or the 0-based feature index).
    attributes : dict of str to list
        Every input attribute column, in input order, ``nf`` values each.
    coords : numpy.ndarray, shape (nv, 3)
        All vertices of all features, in the project CRS; Z is NaN where the layer had
        none and no DEM was sampled yet.
    vertex_feature : numpy.ndarray of int, shape (nv,)
        Index of the feature each vertex belongs to.
    vertex_index : numpy.ndarray of int, shape (nv,)
        0-based vertex index along its feature, continuing across parts.
    vertex_part : numpy.ndarray of int, shape (nv,)
        Part number within the feature (0 for single LineStrings).
    problems : dict of int to str
        Features that cannot be adjusted (empty/null geometry, ...) and why; they are
        carried to the outputs flagged, never dropped.
    crs : str or None
        CRS of ``coords`` (WKT or authority string).
    source : str
        File path, for error messages.
    geometry_type : str
        Geometry type as read (for messages).
    reading : dict
        What the reader reports about the layer (filter, counts, CRS transformation,
        ``excluded_feature_ids``); empty when the layer was not read from a file.
    dem : DemGrid or None
        The DEM the vertices' Z were interpolated in, when it is in the project CRS: a
        database found shifted (an estimated offset) takes its heights from the DEM at
        the shifted position, not where its vertices were.
    """

    name: str
    feature_ids: np.ndarray
    attributes: dict[str, list]
    coords: np.ndarray
    vertex_feature: np.ndarray
    vertex_index: np.ndarray
    vertex_part: np.ndarray
    problems: dict[int, str] = field(default_factory=dict)
    crs: Optional[str] = None
    source: str = "<layer>"
    geometry_type: str = "LineString"
    reading: dict = field(default_factory=dict)
    dem: Optional[DemGrid] = None

    def __post_init__(self) -> None:
        self.feature_ids = np.asarray(self.feature_ids, dtype=object).astype(str)
        self.coords = np.asarray(self.coords, float).reshape(-1, 3)
        self.vertex_feature = np.asarray(self.vertex_feature, dtype=np.int64)
        self.vertex_index = np.asarray(self.vertex_index, dtype=np.int64)
        self.vertex_part = np.asarray(self.vertex_part, dtype=np.int64)

    @property
    def n_features(self) -> int:
        """Number of features (including unadjustable ones)."""
        return len(self.feature_ids)

    @classmethod
    def from_parts(cls, name, feature_ids, attributes, parts, vertex_feature, vertex_index,
                   vertex_part, problems, crs, source, geometry_type) -> LineLayer:
        """Build a layer from per-part vertex arrays (as collected by a reader).

        ``parts``, ``vertex_feature``, ``vertex_index`` and ``vertex_part`` are lists with
        one array per feature part. A feature with a NaN coordinate becomes unadjustable
        (listed in ``problems`` as "NaN coordinates", its vertices removed), never mended.
        """
        if parts:
            xyz = np.concatenate(parts)
            vf, vi, vp = (np.concatenate(a) for a in (vertex_feature, vertex_index, vertex_part))
        else:
            xyz = np.zeros((0, 3))
            vf = vi = vp = np.zeros(0, np.int64)
        problems = dict(problems)
        bad = np.flatnonzero(~np.isfinite(xyz[:, :2]).all(axis=1))
        if bad.size:
            for f in np.unique(vf[bad]):
                problems[int(f)] = "NaN coordinates"
            keep = ~np.isin(vf, list(problems))
            xyz, vf, vi, vp = xyz[keep], vf[keep], vi[keep], vp[keep]
        return cls(name, feature_ids, attributes, xyz, vf, vi, vp, problems, crs, source,
                   geometry_type)


@dataclass
class VectorSpec:
    """One ``[[vectors]]`` entry of the project (a road database).

    ``identification_sigma`` is the (horizontal, vertical) uncertainty of where the
    analyst's measured point lies relative to the real road vertex (object space, m;
    None: not given). ``offset`` is the systematic offset estimated for the database:
    ``"shift"`` (horizontal, the default), ``"shift3d"`` or ``"none"`` (docs/method.md section 10).
    """

    name: str
    path: Optional[str] = None
    id_field: Optional[str] = None
    sigma: tuple[float, float, float] = (10.0, 10.0, 10.0)
    dem: Optional[str] = None
    truth: Optional[str] = None
    layer: Optional[str] = None
    identification_sigma: Optional[tuple[float, float]] = None
    offset: str = "shift"
    #: attribute filter applied when the layer is read (an OGR SQL WHERE clause, e.g.
    #: ``highway IS NOT NULL``); None: every feature
    where: Optional[str] = None
    #: ``"adjust"`` (default) or ``"control"``: a control database's coordinates fix the
    #: datum with their stated sigma; its offset is never estimated freely (a database
    #: cannot be offset against itself), only its stated systematic part is carried
    role: str = "adjust"
    #: (horizontal, vertical) systematic part of ``sigma`` (m): an error common to all the
    #: database's vertices (a datum or digitising bias); None: not stated (zero)
    systematic_sigma: Optional[tuple[float, float]] = None

    @property
    def systematic_variance(self) -> np.ndarray:
        """Per-axis variance (3,) of the systematic part (zeros when not given)."""
        if self.systematic_sigma is None:
            return np.zeros(3)
        h, v = (float(s) for s in self.systematic_sigma)
        return np.array([h * h, h * h, v * v])

    @property
    def identification_variance(self) -> np.ndarray:
        """Per-axis variance (3,) of the identification error (zeros when not given)."""
        if self.identification_sigma is None:
            return np.zeros(3)
        h, v = (float(s) for s in self.identification_sigma)
        return np.array([h * h, h * h, v * v])


@dataclass
class AdjustmentSettings:
    """``[adjustment]`` settings."""

    max_iterations: int = 20
    reweight: str = "none"
    alpha: float = 0.05
    tolerance_position: float = 1e-4
    tolerance_angle: float = 1e-8
    merge_tolerance: float = 0.001
    snooping: bool = False
    alpha0: float = 0.001
    beta0: float = 0.2
    max_removals: Optional[int] = None
    covariance_scale: str = "auto"
    #: a vertex of a database in the run within this distance (m, XY) of a measured vertex
    #: of a database not in the run reuses that vertex's measurements (None: never)
    reuse_tolerance: Optional[float] = None
    #: which vertices reuse: "intersections" (object points where features meet, in both
    #: databases) or "all"
    reuse_points: str = "intersections"
    #: ``"auto"``: the datum from the control, camera priors and control databases given
    #: (checked before the solve); ``"free"``: a free network (no priors, inner
    #: constraints), relative precision only
    datum: str = "auto"
    #: interior parameters estimated with the bundle (self-calibration): a subset of
    #: ``("f", "x0", "y0", "k1", "k2")``; empty: the camera's calibration is fixed
    self_calibration: tuple = ()


@dataclass
class ProjectData:
    """Everything the adjustment needs, as arrays.

    Attributes
    ----------
    crs : str
        Ground CRS (projected, metres).
    camera : Camera
    images : list of ImageSpec
    measurements : Measurements
    control : ControlPoints
    vectors : list of tuple (VectorSpec, LineLayer)
        Road databases with Z already filled (from DEM or geometry).
    settings : AdjustmentSettings
    truth : dict of str to (numpy.ndarray of str, numpy.ndarray (n, 3)), optional
        Per database name: shape point ids and their true coordinates (simulations).
    corrections : dict
        ``[corrections]`` switches.
    source : str
        Project file path, for messages.
    interior : dict
        Report of the image coordinate refinement (interior orientation), passed to
        the summary as ``interior_orientation``.
    qa : dict or None
        The ``[qa]`` table (product specification for accuracy control).
    conflation : dict or None
        The ``[conflation]`` table (None: the defaults, conflation on).
    """

    crs: str
    camera: Camera
    images: list[ImageSpec]
    measurements: Measurements
    control: ControlPoints
    vectors: list = field(default_factory=list)
    settings: AdjustmentSettings = field(default_factory=AdjustmentSettings)
    truth: dict = field(default_factory=dict)
    corrections: dict = field(default_factory=dict)
    source: str = "<project>"
    interior: dict = field(default_factory=dict)
    qa: Optional[dict] = None
    conflation: Optional[dict] = None
    #: warnings of the reading that the run repeats (e.g. images without a trajectory row)
    reading_warnings: list = field(default_factory=list)
    #: object coordinates to longitude, latitude and ellipsoidal height
    #: (:class:`vectoradjust.sensor.ground.GroundFrame`); needed by RPC images, None without
    ground_frame: Any = None

    @property
    def has_rpc(self) -> bool:
        """Whether any image has an RPC model."""
        return any(im.model == "rpc" for im in self.images)
