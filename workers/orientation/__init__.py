"""EXIF orientation fixer (Shima & Shukuya): find which way is up in a photo and tag it losslessly.

Faces first (the paper), then text (Tesseract OSD, optional), never a guess: a photo neither cue
decides clearly is rejected for review.

Modules: ``headers`` (container parsing without decoding), ``decode`` (checked, reduced-size grey
decoding), ``geometry`` (the four rotations), ``faces`` (Haar and YuNet face finders), ``parts``
(facial parts and their arrangement), ``detect`` (detectors, the exactly-one decision, the engine),
``text`` (the text cue: Tesseract OSD on the four views),
``exif`` (the Orientation tag), ``orient`` (the reports; analyze / orient_file), ``job`` (the batch job) and
``blocks`` (its blocks of photos, fanned out and resumed), ``cli`` (``sweepcast orient``) with ``library`` (one file
of a library on disk), ``pool`` (the processes that analyse them) and ``resume`` (what a run remembers).
"""
