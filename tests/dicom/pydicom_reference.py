#!/usr/bin/python3
"""Reference stored values from pydicom for data_pydicom.cpp.

Usage: pydicom_reference.py INPUT_DIR OUTPUT_DIR

Walks INPUT_DIR recursively and, for every file (DICOM or not), records in
OUTPUT_DIR/index.json whether pydicom decodes its pixel data and, if so, the shape and
the stored values: pixel_array without the modality LUT, masked to BitsStored below
HighBit and sign-extended (PS3.5 8.1.1). The values of file number N are written to
OUTPUT_DIR/N.f64 as raw little-endian float64, frame-major then row-major, which is the
layout of octoray::dicom::DecodedImage::stored.
"""

import json
import os
import sys
import traceback

import numpy as np
import pydicom


def stored_values(ds, array):
    """pixel_array as stored values: raw bits masked to BitsStored, then sign-extended.

    pydicom 2.3 already does this for native data with HighBit == BitsStored - 1; doing it
    again here is idempotent and covers the decoders and HighBit layouts where it does not.
    """
    if array.dtype.kind == "f":
        return array.astype(np.float64)
    bits_allocated = int(ds.BitsAllocated)
    bits_stored = int(ds.get("BitsStored", bits_allocated))
    high_bit = int(ds.get("HighBit", bits_stored - 1))
    signed = int(ds.get("PixelRepresentation", 0)) == 1
    raw = array.astype(np.int64) & ((1 << bits_allocated) - 1)
    shift = high_bit + 1 - bits_stored
    bits = (raw >> shift) & ((1 << bits_stored) - 1)
    if signed:
        bits = np.where(bits >= (1 << (bits_stored - 1)), bits - (1 << bits_stored), bits)
    return bits.astype(np.float64)


def describe(path):
    """What pydicom makes of one file: a dict for the JSON index, and the values or None."""
    entry = {"path": path, "decoded": False}
    try:
        ds = pydicom.dcmread(path, force=True)
    except Exception as error:  # any exception: the file is not DICOM pydicom can parse
        entry["reason"] = "dcmread: " + type(error).__name__ + ": " + str(error)[:200]
        return entry, None
    meta = getattr(ds, "file_meta", None)
    syntax = meta.get("TransferSyntaxUID") if meta is not None else None
    entry["syntax"] = str(syntax) if syntax else ""
    for keyword in ("SamplesPerPixel", "PhotometricInterpretation", "BitsAllocated",
                    "BitsStored", "HighBit", "PixelRepresentation", "Rows", "Columns",
                    "NumberOfFrames"):
        try:
            value = ds.get(keyword)
        except Exception:  # a malformed element must not stop the survey
            value = None
        if value is not None and value != "":
            entry[keyword] = str(value)
    if "PixelData" not in ds and "FloatPixelData" not in ds and "DoubleFloatPixelData" not in ds:
        entry["reason"] = "no pixel data element"
        return entry, None
    if not entry["syntax"]:
        # pydicom guesses the encoding of files without meta; record what it read them as.
        little = getattr(ds, "is_little_endian", True)
        implicit = getattr(ds, "is_implicit_VR", True)
        entry["syntax"] = ("1.2.840.10008.1.2" if implicit else
                           ("1.2.840.10008.1.2.1" if little else "1.2.840.10008.1.2.2"))
        entry["syntaxGuessed"] = True
    try:
        array = ds.pixel_array
    except Exception as error:
        entry["reason"] = "pixel_array: " + type(error).__name__ + ": " + str(error)[:200]
        return entry, None
    try:
        samples = int(ds.get("SamplesPerPixel", 1))
        frames = int(ds.get("NumberOfFrames", 1) or 1)
        rows, columns = int(ds.Rows), int(ds.Columns)
        if samples != 1:
            entry["reason"] = "colour image (SamplesPerPixel %d)" % samples
            entry["colour"] = True
            return entry, None
        if array.size != frames * rows * columns:
            entry["reason"] = "pixel_array has %d samples, %d frames x %d x %d expected" % (
                array.size, frames, rows, columns)
            return entry, None
        values = stored_values(ds, array).reshape(-1)
    except Exception as error:
        entry["reason"] = "values: " + type(error).__name__ + ": " + str(error)[:200]
        return entry, None
    entry.update({"decoded": True, "frames": frames, "rows": rows, "columns": columns})
    return entry, values


def main():
    if len(sys.argv) != 3:
        sys.stderr.write(__doc__)
        return 2
    root, out_dir = sys.argv[1], sys.argv[2]
    os.makedirs(out_dir, exist_ok=True)
    paths = []
    for folder, _, names in os.walk(root):
        paths.extend(os.path.join(folder, name) for name in names)
    paths.sort()
    index = []
    for number, path in enumerate(paths):
        try:
            entry, values = describe(path)
        except Exception:  # never let one file end the survey
            entry, values = {"path": path, "decoded": False,
                             "reason": "survey failed: " + traceback.format_exc(limit=1)}, None
        if values is not None:
            name = "%d.f64" % number
            values.astype("<f8").tofile(os.path.join(out_dir, name))
            entry["values"] = name
        index.append(entry)
    with open(os.path.join(out_dir, "index.json"), "w") as stream:
        json.dump({"pydicom": pydicom.__version__, "files": index}, stream, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
