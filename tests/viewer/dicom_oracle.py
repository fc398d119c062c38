"""An independent reference for the viewer's MPR views: reads a DICOM series with pydicom,
builds its index-to-patient geometry from the headers (ImagePositionPatient,
ImageOrientationPatient, PixelSpacing; a gantry tilt shows as IPP steps that are not along the
slice normal), and samples planes with its own trilinear interpolation in numpy. Nothing here
uses octoray's code."""
import os

import numpy as np
import pydicom


class DicomVolume:
    def __init__(self, folder):
        slices = []
        for name in sorted(os.listdir(folder)):
            path = os.path.join(folder, name)
            if not os.path.isfile(path):
                continue
            try:
                ds = pydicom.dcmread(path)
            except Exception:
                continue
            if "PixelData" not in ds or "ImagePositionPatient" not in ds:
                continue
            slices.append(ds)
        if not slices:
            raise RuntimeError(f"{folder}: no images")
        iop = np.array(slices[0].ImageOrientationPatient, dtype=float)
        row, col = iop[:3], iop[3:]
        normal = np.cross(row, col)
        slices.sort(key=lambda d: float(np.dot(np.array(d.ImagePositionPatient, dtype=float), normal)))
        ps = [float(v) for v in slices[0].PixelSpacing]  # row spacing, column spacing
        ipp = np.array([np.array(d.ImagePositionPatient, dtype=float) for d in slices])
        # One slice: no spacing to read from positions; octoray's reader takes 1 mm along the
        # normal (and says so), which only places the slab a plane through the slice samples.
        step = (ipp[-1] - ipp[0]) / (len(slices) - 1) if len(slices) > 1 else normal
        self.affine = np.eye(4)
        self.affine[:3, 0] = row * ps[1]
        self.affine[:3, 1] = col * ps[0]
        self.affine[:3, 2] = step
        self.affine[:3, 3] = ipp[0]
        self.inverse = np.linalg.inv(self.affine)
        vol = []
        for d in slices:
            slope = float(getattr(d, "RescaleSlope", 1.0))
            intercept = float(getattr(d, "RescaleIntercept", 0.0))
            vol.append(d.pixel_array.astype(np.float64) * slope + intercept)
        self.values = np.stack(vol)  # [k, j, i]
        self.dims = np.array([self.values.shape[2], self.values.shape[1], self.values.shape[0]])

    def patient(self, i, j, k):
        return (self.affine @ np.array([i, j, k, 1.0]))[:3]

    def sample(self, points):
        """Trilinear values at patient points (N x 3); NaN outside [-0.5, dim - 0.5]."""
        pts = np.asarray(points, dtype=float).reshape(-1, 3)
        q = (self.inverse[:3, :3] @ pts.T).T + self.inverse[:3, 3]
        inside = np.all((q >= -0.5) & (q <= self.dims - 0.5), axis=1)
        p = np.clip(q, 0, self.dims - 1)
        i0 = np.minimum(np.floor(p), np.maximum(self.dims - 2, 0)).astype(int)
        f = p - i0
        v = self.values
        out = np.zeros(len(pts))
        for dz in (0, 1):
            for dy in (0, 1):
                for dx in (0, 1):
                    w = (f[:, 0] if dx else 1 - f[:, 0]) * (f[:, 1] if dy else 1 - f[:, 1]) * (f[:, 2] if dz else 1 - f[:, 2])
                    out += w * v[np.minimum(i0[:, 2] + dz, self.dims[2] - 1),
                                 np.minimum(i0[:, 1] + dy, self.dims[1] - 1),
                                 np.minimum(i0[:, 0] + dx, self.dims[0] - 1)]
        out[~inside] = np.nan
        return out

    def plane_values(self, plane):
        """The values at the centres of a view's pixels (plane: origin, right, down, mmPerPixel,
        width, height, as octoray-view's state file reports them)."""
        w, h, s = plane["width"], plane["height"], plane["mmPerPixel"]
        origin, right, down = (np.array(plane[k], dtype=float) for k in ("origin", "right", "down"))
        xs = (np.arange(w) + 0.5) * s
        ys = (np.arange(h) + 0.5) * s
        pts = origin + xs[None, :, None] * right + ys[:, None, None] * down
        return self.sample(pts.reshape(-1, 3)).reshape(h, w)


def window_grey_exact(values, window, level):
    """DICOM PS3.3 C.11.2.1.3.2 LINEAR_EXACT VOI LUT to 0..255 (any window above 0), rounded
    half up; NaN to 0."""
    c, w = float(level), float(window)
    g = np.floor(((values - c) / w + 0.5) * 255.0 + 0.5)
    g = np.where(values <= c - w / 2, 0, g)
    g = np.where(values > c + w / 2, 255, g)
    g = np.where(np.isnan(values), 0, g)
    return np.clip(g, 0, 255).astype(np.uint8)


def window_grey_sigmoid(values, window, level):
    """DICOM PS3.3 C.11.2.1.3.1 SIGMOID VOI LUT to 0..255, by pydicom's own implementation
    (apply_windowing on an unsigned 16-bit MONOCHROME2 dataset: output 0..65535), scaled to
    0..255 and rounded half up; NaN to 0."""
    from pydicom.dataset import Dataset
    from pydicom.pixel_data_handlers.util import apply_windowing
    ds = Dataset()
    ds.PhotometricInterpretation = "MONOCHROME2"
    ds.BitsStored = 16
    ds.PixelRepresentation = 0
    ds.WindowCenter = float(level)
    ds.WindowWidth = float(window)
    ds.VOILUTFunction = "SIGMOID"
    finite = np.where(np.isnan(values), 0.0, values)
    with np.errstate(over="ignore"):
        y = apply_windowing(finite.astype(np.float64), ds)
    g = np.floor(y / 65535.0 * 255.0 + 0.5)
    g = np.where(np.isnan(values), 0, g)
    return np.clip(g, 0, 255).astype(np.uint8)


def window_grey(values, window, level):
    """DICOM PS3.3 C.11.2.1.2.1 linear VOI LUT to 0..255, rounded half up; NaN to 0."""
    c, w = float(level), max(1.0, float(window))
    y = ((values - (c - 0.5)) / (w - 1) + 0.5) * 255.0
    g = np.floor(y + 0.5)
    g = np.where(values <= c - 0.5 - (w - 1) / 2, 0, g)
    g = np.where(values > c - 0.5 + (w - 1) / 2, 255, g)
    g = np.where(np.isnan(values), 0, g)
    return np.clip(g, 0, 255).astype(np.uint8)
