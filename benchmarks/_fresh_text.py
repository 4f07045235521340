"""A fresh held-out set for the orientation text cue: real pages, scans, signs and screens nobody has run the engine on.

Assembled after the Leptonica set (:mod:`benchmarks._leptonica`) had been read, so that a final benchmark run has
images the text cue was never built, tuned or checked on. Both lists below were fixed by looking at the images alone
(downscaled copies and contact sheets, nothing else read them: no OCR, nothing of ``workers.orientation``); the
commit that adds this file holds no figure from them. Nothing here overlaps what the project already uses: Leptonica's
``prog/`` images, the files of ``$SWEEPCAST_DATA/orientation`` (its PROVENANCE; Tesseract's ``hebtypo.jpg`` is one of
them and is left out here), scikit-image's data, Debian's wallpapers and MyPaint's textures (checked by a coarse image
correlation at the four turns as well as by name: the only matches were ``hebtypo.jpg`` and OpenCV's chessboard, a
copy of scikit-image's, neither listed).

Fetched on the benchmark machine, each archive checked by its SHA-256 (the one Debian's archive index or PyPI's
simple index gives), never committed; kept for benchmark use on this machine only. Sources, file-name prefixes and
licences:

- ``tesseract``: Tesseract's test data (``testing/``), the ``orig-test`` tarball of Debian's ``tesseract`` source
  package (the tesseract-ocr/test repository); Apache-2.0 (its LICENSE; no per-image licence; the two magazine pages
  ``8071_093.3B``/``8087_054.3B`` look like the UNLV-ISRI OCR test set's).
- ``unpaper``: unpaper's test input pages (``tests/source_images``), Debian's ``unpaper`` upstream tarball;
  GPL-2.0-only (REUSE ``.license`` files beside each image).
- ``gocr``: GOCR's handwriting example, Debian's ``gocr`` upstream tarball; GPL-2.0-or-later.
- ``ocrad``: GNU Ocrad's test page (``testsuite/test.pbm``), Debian's ``ocrad`` upstream tarball; GPL-2.0-or-later.
- ``opencv``: OpenCV's sample data (``samples/data``) and the text module's scene-text samples, as installed by
  Debian's binary package ``opencv-doc`` (4.6.0, ``examples/``); Apache-2.0 (OpenCV >= 4.5; Debian's copyright
  file; no per-image licence, some photos, e.g. baboon, apple, orange, are the old USC-SIPI test images).
- ``ocrmypdf``: OCRmyPDF's test resources, its PyPI sdist (17.13.0); per file (its REUSE.toml): ``c03-29``,
  ``multipage`` public domain (Project Gutenberg scans), ``linn`` GFDL-1.2+/CC-BY-SA-3.0, ``typewriter``
  GFDL-1.2+/CC-BY-SA, ``epson``/``masks`` CC-BY-SA-3.0 (Wikipedia printouts), ``francais``/``kcs`` CC-BY-SA-4.0;
  the flatpak screenshot (``misc/flatpak``) has no entry there, so the package's MPL-2.0.
- ``pikepdf``: pikepdf's test resources and documentation photos, its PyPI sdist (9.9.0); MPL-2.0 (the sdist states
  no per-file licence; the Senate page and the two forms are US-government works).
- ``pypdf``: pypdf's test resources, its PyPI sdist (7.1.1); BSD-3-Clause (the sdist states no per-file licence; a
  scanned 19th-century book and a scanned shipping-agreement appendix).
- ``img2table``: img2table's examples and test images, its PyPI sdist (2.0.0); MIT.
- ``jdeskew``: jdeskew's paper and test page, its PyPI sdist (0.4.2); MIT (its README asks to respect the licences of
  the data sets it builds on).

PDF pages are rendered with pypdfium2 (``pip install pypdfium2``; 5.15 when the lists were fixed) at ``DPI`` = 150,
the page's own /Rotate applied, as RGB PNG: ``<source>__<pdf stem>.p<page>.png``. Every other file is copied
byte-for-byte as ``<source>__<file>`` (img2table's ``borderless/1.png`` ... as ``borderless-1.png`` ..., its two
``test`` images by their folder).

Rule for ``TEXT`` (as for Leptonica's): lines of text (printed, typed, or block handwriting, any script) are what the
image shows, a person reads them at a glance, the image is upright as stored (text reads normally, not turned), and
its short side is at least 300 px; one image per page or scene. It holds scanned book and magazine pages (English,
Hebrew with vowel points, Devanagari, 19th-century prints), forms, a bank statement and an invoice, a scientific
paper, typewriter and handwritten lines, photos of signs (English, German, French) and screenshots (a terminal, a PDF
viewer, a web table). Doubtful but kept: ``opencv__imageTextR.png`` (a page stored about 7 degrees askew; it reads
normally), ``ocrad__test.pbm`` (a character chart, one line per alphabet), ``unpaper__imgsrc002.png`` and
``unpaper__imgsrcE001.png`` (typeset filler text, "some text here" / "left page right page"), ``gocr__handwrt1.jpg``
and ``ocrmypdf__kcs.p1.png`` (two or three handwritten lines), ``opencv__scenetext_segmented_word05.jpg`` (three lines
of a projector's maker logo and model), ``pikepdf__save-pike.jpg`` (a weathered sign, its paint partly worn off).

Left out under that rule: rotated copies (Tesseract's ``phototest-rotated-*``, ``phototestrot``,
``devatest-rotated-270``; OCRmyPDF's ``cardinal``, ``rotated_skew``, ``skew``), other renderings of a listed page
(``8087_054.3G``, ``phototest_2``; unpaper's ``imgsrc001`` and ``imgsrcE002/E003``; OCRmyPDF's ``linn.pdf``,
``ccitt``, ``jbig2*``, ``poster``, ``2400dpi``, ``multipage`` pages 1-4 and 6, ``baiona_*``; pikepdf's ``congress``,
``congress_im0``, ``jbig2``, ``jbig2global``, ``sandwich``; pypdf's ``*-crazyones-merged``; img2table's copies of its
``test.png``), pages of a document already listed (pypdf's Vicksburg pages 2-3 and its appendix's pages 2, 4, 5; the
forms' later pages; jdeskew's paper after page 1), maps and charts (``baiona``, ``graph``, img2table's ``tables``),
drawings and diagrams with labels (unpaper's ``doc/img``, ``28fish``, ``vector``), a line or two in a blank page
(Tesseract's ``training*`` and ``segmodeimg``; ``aspect``, ``cmyk``, most of pypdf's synthetic PDFs), single words or
one line on a sign (unpaper's hand-drawn ``imgsrc003-005``, OpenCV's ``HOTEL``, ``FOSTER'S``, ``Stationery Box``, ``copy
centre``, ``GM 125``, ``NO PARKING``, the shopfront ``scenetext06``), blurred text (``text_defocus``, ``text_motion``,
``licenseplate_motion``), book covers in a room (``left.jpg``/``right.jpg``), a sudoku, logos and UI screenshots,
synthetic grid tables (img2table's ``test.png``, ``implicit``), images under 300 px (``imageTextN``, ``hebrew.png``,
gocr's fonts), and pypdf's ``issue-604`` (NCCN guidelines: dense flow charts, and its copyright forbids reproduction).

Rule for ``NO_TEXT``: photos with nothing to read anywhere in them. Left out: a circuit board (chip labels), the
footballer (shirt sponsor), the rubber whale (foam letters), the desk still life (a lighter and a coin), the plant
(price label), the basketball pair (a notice on the wall), The Starry Night (a painting), renders and drawings
(``Blender_Suzanne*``, ``pic1-6``, ``cards``, shapes, the anime face of ``fuzzy``), and second views of a listed scene
(``aloeR``, ``leuvenB``, ``ela_modified``, ``rubberwhale2``, the calibration boards).
"""
from __future__ import annotations

import functools
import hashlib
import io
import os
import shutil
import tarfile
import urllib.request
from pathlib import Path

SOURCE = "fresh"
"""The text photos' source name (``fresh__<source>__<file>``) and the no-text category."""
DPI = 150
"""The resolution PDF pages are rendered at (pixels per inch)."""

_DEBIAN = "http://deb.debian.org/debian/pool/main"
_PYPI = "https://files.pythonhosted.org/packages"
ARCHIVES: dict[str, tuple[str, str]] = {
    "tesseract": (f"{_DEBIAN}/t/tesseract/tesseract_5.3.0.orig-test.tar.gz",
                  "2788d27de6e448f8ffa7dd19a22c5781768440dee60a34607099f0c66d44b911"),
    "unpaper": (f"{_DEBIAN}/u/unpaper/unpaper_7.0.0.orig.tar.xz",
                "2575fbbf26c22719d1cb882b59602c9900c7f747118ac130883f63419be46a80"),
    "gocr": (f"{_DEBIAN}/g/gocr/gocr_0.52.orig.tar.gz",
             "df906463105f5f4273becc2404570f187d4ea52bd5769d33a7a8661a747b8686"),
    "ocrad": (f"{_DEBIAN}/o/ocrad/ocrad_0.29.orig.tar.gz",
              "8f248e64a6ddff6d1dd20fc530078eaaa4ff9f8289d989146a7cbdecec57fb40"),
    "opencv": (f"{_DEBIAN}/o/opencv/opencv-doc_4.6.0+dfsg-12_all.deb",
               "4b12681df35878207ac7097dc66184b2ae552e4bf4ddd2af04a0f03ed0b8682a"),
    "ocrmypdf": (f"{_PYPI}/d9/1b/d35a3c9bb4e4959bd782808f0eb45cce16e66040a292b7f4eaa6a6e44ff1/ocrmypdf-17.13.0.tar.gz",
                 "151c35d810eb628fbc5cb9bbe80b834ecf094737efa0e7a2e9e1fac3c730ed49"),
    "pikepdf": (f"{_PYPI}/89/15/c6faef352a55a13d11738e56d5b4b309fb43d216e26c70206b9159694846/pikepdf-9.9.0.tar.gz",
                "948620612c5ee70c14b262a352b1db927386eab741d6ed77fdb1c4c8772734b9"),
    "pypdf": (f"{_PYPI}/96/5f/f41984a8150ec37c6ee50fa6fa1868d065337b65ba510a155848b2ce0b62/pypdf-7.1.1.tar.gz",
              "2eff4e2fc5fb22a6d6711e6f1166cdc9ab5765d90cd0d77dfea3f4aa91a27b1d"),
    "img2table": (f"{_PYPI}/64/3a/3f787fe41f620200273cb6faf46ba9054eafb60a37472407c33a04adadcd/img2table-2.0.0.tar.gz",
                  "584334b46c898d733a2a44941df96bed2fefb2cd5e89ae57830614e6119be06f"),
    "jdeskew": (f"{_PYPI}/03/63/f8048f65d813eb3775543d88af37ce4fa861b2cda14febac5abfa49726cd/jdeskew-0.4.2.tar.gz",
                "27b18400172b6b81d700304aa67b67256f2433b7714dd0d48173ed39d9a585cd"),
}
"""Each source's archive (a Debian pool file or a PyPI sdist) and its SHA-256."""

_OPENCV = "usr/share/doc/opencv-doc/examples"
FILES: dict[str, str] = {
    # name (its prefix names the archive): the member inside the archive, below the archive's top folder (a .deb:
    # its data tarball's path); "#pN": page N of that PDF, rendered at DPI
    "tesseract__8071_093.3B.tif": "testing/8071_093.3B.tif",
    "tesseract__8087_054.3B.tif": "testing/8087_054.3B.tif",
    "tesseract__devatest.png": "testing/devatest.png",
    "tesseract__eurotext.tif": "testing/eurotext.tif",
    "tesseract__hebrew-nikud-genesis-1-2.png": "testing/hebrew-nikud-genesis-1-2.png",
    "tesseract__phototest.tif": "testing/phototest.tif",
    "unpaper__imgsrc002.png": "tests/source_images/imgsrc002.png",
    "unpaper__imgsrcE001.png": "tests/source_images/imgsrcE001.png",
    "gocr__handwrt1.jpg": "examples/handwrt1.jpg",
    "ocrad__test.pbm": "testsuite/test.pbm",
    "opencv__imageTextR.png": f"{_OPENCV}/data/imageTextR.png",
    "opencv__scenetext01.jpg": f"{_OPENCV}/text/scenetext01.jpg",
    "opencv__scenetext02.jpg": f"{_OPENCV}/text/scenetext02.jpg",
    "opencv__scenetext_segmented_word03.jpg": f"{_OPENCV}/text/scenetext_segmented_word03.jpg",
    "opencv__scenetext_segmented_word05.jpg": f"{_OPENCV}/text/scenetext_segmented_word05.jpg",
    "ocrmypdf__c03-29.p1.png": "tests/resources/c03-29.pdf#p1",
    "ocrmypdf__epson.p1.png": "tests/resources/epson.pdf#p1",
    "ocrmypdf__francais.p1.png": "tests/resources/francais.pdf#p1",
    "ocrmypdf__kcs.p1.png": "tests/resources/kcs.pdf#p1",
    "ocrmypdf__linn.png": "tests/resources/linn.png",
    "ocrmypdf__masks.p1.png": "tests/resources/masks.pdf#p1",
    "ocrmypdf__multipage.p5.png": "tests/resources/multipage.pdf#p5",
    "ocrmypdf__sample_screenshot.png": "misc/flatpak/sample_screenshot.png",
    "ocrmypdf__typewriter.png": "tests/resources/typewriter.png",
    "pikepdf__congress-gray.p1.png": "tests/resources/congress-gray.pdf#p1",
    "pikepdf__form_210966.p1.png": "tests/resources/form_210966.pdf#p1",
    "pikepdf__form_dd0293.p1.png": "tests/resources/form_dd0293.pdf#p1",
    "pikepdf__save-pike.jpg": "docs/images/save-pike.jpg",
    "pypdf__Seige_of_Vicksburg_Sample_OCR.p1.png": "resources/Seige_of_Vicksburg_Sample_OCR.pdf#p1",
    "pypdf__Seige_of_Vicksburg_Sample_OCR.p4.png": "resources/Seige_of_Vicksburg_Sample_OCR.pdf#p4",
    "pypdf__Seige_of_Vicksburg_Sample_OCR.p5.png": "resources/Seige_of_Vicksburg_Sample_OCR.pdf#p5",
    "pypdf__Seige_of_Vicksburg_Sample_OCR.p6.png": "resources/Seige_of_Vicksburg_Sample_OCR.pdf#p6",
    "pypdf__indirect-rotation.p1.png": "resources/indirect-rotation.pdf#p1",
    "pypdf__indirect-rotation.p3.png": "resources/indirect-rotation.pdf#p3",
    "img2table__borderless-1.png": "examples/data/borderless/1.png",
    "img2table__borderless-2.png": "examples/data/borderless/2.png",
    "img2table__borderless-3.png": "examples/data/borderless/3.png",
    "img2table__borderless.jpg": "examples/data/borderless.jpg",
    "img2table__dark.png": "tests/document/image/test_data/dark.png",
    "img2table__surya-test.png": "tests/ocr/surya/test_data/test.png",
    "img2table__layout-test.bmp": "tests/tables/borderless/layout/test_data/test.bmp",
    "jdeskew__icip_paper.p1.png": "icip_paper.pdf#p1",
    "jdeskew__test.png": "tests/test.png",
    "opencv__aero1.jpg": f"{_OPENCV}/data/aero1.jpg",
    "opencv__aero3.jpg": f"{_OPENCV}/data/aero3.jpg",
    "opencv__aloeL.jpg": f"{_OPENCV}/data/aloeL.jpg",
    "opencv__apple.jpg": f"{_OPENCV}/data/apple.jpg",
    "opencv__baboon.jpg": f"{_OPENCV}/data/baboon.jpg",
    "opencv__building.jpg": f"{_OPENCV}/data/building.jpg",
    "opencv__butterfly.jpg": f"{_OPENCV}/data/butterfly.jpg",
    "opencv__chicky_512.png": f"{_OPENCV}/data/chicky_512.png",
    "opencv__ela_original.jpg": f"{_OPENCV}/data/ela_original.jpg",
    "opencv__fruits.jpg": f"{_OPENCV}/data/fruits.jpg",
    "opencv__home.jpg": f"{_OPENCV}/data/home.jpg",
    "opencv__leuvenA.jpg": f"{_OPENCV}/data/leuvenA.jpg",
    "opencv__orange.jpg": f"{_OPENCV}/data/orange.jpg",
    "opencv__pca_test1.jpg": f"{_OPENCV}/data/pca_test1.jpg",
    "opencv__smarties.png": f"{_OPENCV}/data/smarties.png",
    "opencv__squirrel_cls.jpg": f"{_OPENCV}/data/squirrel_cls.jpg",
    "pikepdf__pike-release.jpg": "docs/images/pike-release.jpg",
}

TEXT = (
    "tesseract__8071_093.3B.tif", "tesseract__8087_054.3B.tif", "tesseract__devatest.png", "tesseract__eurotext.tif",
    "tesseract__hebrew-nikud-genesis-1-2.png", "tesseract__phototest.tif",
    "unpaper__imgsrc002.png", "unpaper__imgsrcE001.png",
    "gocr__handwrt1.jpg",
    "ocrad__test.pbm",
    "opencv__imageTextR.png", "opencv__scenetext01.jpg", "opencv__scenetext02.jpg",
    "opencv__scenetext_segmented_word03.jpg", "opencv__scenetext_segmented_word05.jpg",
    "ocrmypdf__c03-29.p1.png", "ocrmypdf__epson.p1.png", "ocrmypdf__francais.p1.png", "ocrmypdf__kcs.p1.png",
    "ocrmypdf__linn.png", "ocrmypdf__masks.p1.png", "ocrmypdf__multipage.p5.png", "ocrmypdf__sample_screenshot.png",
    "ocrmypdf__typewriter.png",
    "pikepdf__congress-gray.p1.png", "pikepdf__form_210966.p1.png", "pikepdf__form_dd0293.p1.png",
    "pikepdf__save-pike.jpg",
    "pypdf__Seige_of_Vicksburg_Sample_OCR.p1.png", "pypdf__Seige_of_Vicksburg_Sample_OCR.p4.png",
    "pypdf__Seige_of_Vicksburg_Sample_OCR.p5.png", "pypdf__Seige_of_Vicksburg_Sample_OCR.p6.png",
    "pypdf__indirect-rotation.p1.png", "pypdf__indirect-rotation.p3.png",
    "img2table__borderless-1.png", "img2table__borderless-2.png", "img2table__borderless-3.png",
    "img2table__borderless.jpg", "img2table__dark.png", "img2table__surya-test.png", "img2table__layout-test.bmp",
    "jdeskew__icip_paper.p1.png", "jdeskew__test.png",
)
NO_TEXT = (
    "opencv__aero1.jpg", "opencv__aero3.jpg", "opencv__aloeL.jpg", "opencv__apple.jpg", "opencv__baboon.jpg",
    "opencv__building.jpg", "opencv__butterfly.jpg", "opencv__chicky_512.png", "opencv__ela_original.jpg",
    "opencv__fruits.jpg", "opencv__home.jpg", "opencv__leuvenA.jpg", "opencv__orange.jpg", "opencv__pca_test1.jpg",
    "opencv__smarties.png", "opencv__squirrel_cls.jpg", "pikepdf__pike-release.jpg",
)
assert set(TEXT) | set(NO_TEXT) == set(FILES) and not set(TEXT) & set(NO_TEXT)


def cache_dir() -> Path:
    """Where the archives and the images taken from them are kept (``$SWEEPCAST_BENCH_CACHE``, default
    ``~/.cache/sweepcast-bench``)."""
    return Path(os.environ.get("SWEEPCAST_BENCH_CACHE", Path.home() / ".cache" / "sweepcast-bench")) / SOURCE


@functools.cache
def images(timeout_s: float = 300) -> Path | None:
    """The folder holding every file of :data:`TEXT` and :data:`NO_TEXT`, fetched and unpacked on first use (about
    140 MB of archives, the largest OpenCV's documentation package); None (with the reason printed) when an archive
    cannot be reached or does not match its checksum, or pypdfium2 is missing for the PDF pages. All or nothing, so
    that every run reads the same set. Decided once per process."""
    folder = cache_dir() / "images"
    missing = sorted(name for name in FILES if not (folder / name).is_file())
    if not missing:
        return folder
    if any("#p" in FILES[name] for name in missing):
        try:
            import pypdfium2  # noqa: F401
        except ImportError:
            print("left out: the fresh text images (pypdfium2 is not installed: pip install pypdfium2)")
            return None
    folder.mkdir(parents=True, exist_ok=True)
    for source in sorted({name.split("__")[0] for name in missing}):
        url, sha256 = ARCHIVES[source]
        archive = cache_dir() / Path(url).name
        try:
            if not archive.is_file():
                part = archive.with_name(archive.name + ".part")
                with urllib.request.urlopen(url, timeout=timeout_s) as answer, part.open("wb") as out:
                    shutil.copyfileobj(answer, out, 1 << 20)
                part.replace(archive)
        except OSError as exc:
            print(f"left out: the fresh text images ({url}: {exc})")
            return None
        if _sha256(archive) != sha256:
            print(f"left out: the fresh text images ({archive} does not match its SHA-256)")
            return None
        wanted = {FILES[name].split("#")[0] for name in missing if name.startswith(source + "__")}
        try:
            members = _members(archive, wanted)
        except (OSError, tarfile.TarError, ValueError) as exc:
            print(f"left out: the fresh text images ({archive}: {exc})")
            return None
        absent = wanted - set(members)
        if absent:
            print(f"left out: the fresh text images ({archive} lacks {min(absent)})")
            return None
        for name in (name for name in missing if name.startswith(source + "__")):
            member, _, page = FILES[name].partition("#p")
            data = _render(members[member], int(page)) if page else members[member]
            part = folder / (name + ".part")
            part.write_bytes(data)
            part.replace(folder / name)
    return folder


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as src:
        for block in iter(lambda: src.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _members(archive: Path, wanted: set[str]) -> dict[str, bytes]:
    """The bytes of each wanted member (path below the archive's top folder; a .deb: its data tarball's path),
    reading the archive once from start to end."""
    if archive.suffix == ".deb":
        stream, strip = io.BytesIO(_deb_data(archive)), lambda name: name.removeprefix("./")
    else:
        stream, strip = archive.open("rb"), lambda name: name.partition("/")[2]
    found: dict[str, bytes] = {}
    with stream, tarfile.open(fileobj=stream, mode="r|*") as tar:
        for member in tar:
            path = strip(member.name)
            if member.isfile() and path in wanted:
                found[path] = tar.extractfile(member).read()
                if len(found) == len(wanted):
                    break
    return found


def _deb_data(deb: Path) -> bytes:
    """The ``data.tar.*`` member of a Debian binary package (an ``ar`` archive)."""
    with deb.open("rb") as src:
        if src.read(8) != b"!<arch>\n":
            raise ValueError("not an ar archive")
        while header := src.read(60):
            name, size = header[:16].decode().strip().rstrip("/"), int(header[48:58])
            if name.startswith("data.tar"):
                return src.read(size)
            src.seek(size + size % 2, os.SEEK_CUR)
    raise ValueError("no data.tar member")


def _render(pdf: bytes, page: int) -> bytes:
    """Page ``page`` (from 1) of ``pdf`` at :data:`DPI`, its /Rotate applied, as an RGB PNG."""
    import pypdfium2

    document = pypdfium2.PdfDocument(pdf)
    try:
        image = document[page - 1].render(scale=DPI / 72).to_pil().convert("RGB")
    finally:
        document.close()
    out = io.BytesIO()
    image.save(out, format="PNG")
    return out.getvalue()
