"""GNSS/INS camera positions from a trajectory CSV (``[trajectory]`` in the project).

One row per image::

    image_id,X,Y,Z[,omega,phi,kappa][,sigma_X,sigma_Y,sigma_Z][,sigma_omega,sigma_phi,sigma_kappa]

(``sigma_position`` / ``sigma_attitude`` may stand for the three sigmas of each). The
values replace the ``[[images]]`` entry's ``position``, ``attitude`` and their sigmas -
they are the camera priors that fix the datum without control points
(:mod:`vectoradjust.adjust.datum`). Positions are in ``[trajectory] crs`` (default: the
project CRS; heights in its ``vertical_crs``) and transformed to the project CRS like
the control points; angles are in degrees in the project's frame. A row for an image
the project does not have, a repeated image, a negative sigma are errors that name the
line; images without a row keep their entry's values (a warning names them).
"""

from __future__ import annotations

import numpy as np

from vectoradjust.errors import CSVError

__all__ = ["read_trajectory", "apply_trajectory", "TRAJECTORY_COLUMNS"]

#: the columns a trajectory CSV may have (image_id, X, Y, Z required)
TRAJECTORY_COLUMNS = ("image_id", "X", "Y", "Z", "omega", "phi", "kappa", "sigma_X",
                      "sigma_Y", "sigma_Z", "sigma_omega", "sigma_phi", "sigma_kappa",
                      "sigma_position", "sigma_attitude")


def read_trajectory(path: str) -> dict:
    """The trajectory table: column arrays (floats but ``image_id``) and ``_line``.

    Raises
    ------
    CSVError
        Missing columns, non-numeric values, a repeated image, a negative sigma.
    """
    from vectoradjust.files.csv_tables import _read_rows, parse_table

    header, rows, lines = _read_rows(path)
    numeric = [c for c in TRAJECTORY_COLUMNS if c != "image_id" and c.lower() in
               {h.strip().lower() for h in header}]
    cols = parse_table(str(path), [h.strip() for h in header], rows, TRAJECTORY_COLUMNS[:4],
                       TRAJECTORY_COLUMNS[4:], numeric=numeric, lines=lines)
    ids = cols["image_id"].astype(str)
    uniq, first, counts = np.unique(ids, return_index=True, return_counts=True)
    if (counts > 1).any():
        dup = str(uniq[counts > 1][0])
        rows_of = cols["_line"][ids == dup]
        raise CSVError(f"{path}: image {dup!r} has more than one row (lines "
                       f"{', '.join(str(int(r)) for r in rows_of)})",
                       "Keep one row per image (the position at its exposure)", path=path)
    for c in (c for c in cols if c.startswith("sigma")):
        bad = np.flatnonzero(~(cols[c] > 0))
        if bad.size:
            raise CSVError(f"{path}, line {int(cols['_line'][bad[0]])}: {c} must be positive, "
                           f"not {cols[c][bad[0]]}", "Give the GNSS/INS sigma in metres "
                           "(positions) or degrees (angles)", path=path)
    return cols


def _three(cols: dict, names: tuple, one: str, i: int):
    """A per-axis sigma from three columns, or one column for all three (None: none)."""
    if all(n in cols for n in names):
        return tuple(float(cols[n][i]) for n in names)
    if one in cols:
        return (float(cols[one][i]),) * 3
    return None


def apply_trajectory(images: list, cols: dict, xyz: np.ndarray, source: str,
                     warnings: list) -> None:
    """Put the trajectory's positions, attitudes and sigmas into the ``[[images]]``
    entries (in place).

    Parameters
    ----------
    images : list of ImageSpec
    cols : dict
        From :func:`read_trajectory`.
    xyz : numpy.ndarray, shape (n, 3)
        The rows' positions in the project CRS.
    source : str
        The CSV's name for messages.
    warnings : list of str
        Appended to: images without a row.
    """
    by_id = {str(im.id): im for im in images}
    ids = [str(v) for v in cols["image_id"]]
    for i, iid in enumerate(ids):
        im = by_id.get(iid)
        if im is None:
            raise CSVError(f"{source}, line {int(cols['_line'][i])}: image {iid!r} is not in "
                           "the project's [[images]]",
                           "Add an [[images]] entry with that id, or correct the id", path=source)
        if im.model == "rpc":
            raise CSVError(f"{source}, line {int(cols['_line'][i])}: image {iid!r} is an RPC "
                           "image; it has no camera position", "Remove its row", path=source)
        im.position = np.asarray(xyz[i], float)
        if all(a in cols for a in ("omega", "phi", "kappa")):
            im.attitude = np.array([cols[a][i] for a in ("omega", "phi", "kappa")], float)
        sp = _three(cols, ("sigma_X", "sigma_Y", "sigma_Z"), "sigma_position", i)
        sa = _three(cols, ("sigma_omega", "sigma_phi", "sigma_kappa"), "sigma_attitude", i)
        if sp is not None:
            im.sigma_position = sp
        if sa is not None:
            im.sigma_attitude = sa
    missing = [str(im.id) for im in images if im.model != "rpc" and str(im.id) not in set(ids)]
    if missing:
        warnings.append(f"{source}: no trajectory row for image(s) {', '.join(missing[:10])}"
                        + (" ..." if len(missing) > 10 else "") + "; they keep their "
                        "[[images]] position and sigmas")
