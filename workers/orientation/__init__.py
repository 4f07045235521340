"""EXIF orientation fixer (Shima & Shukuya): find which way is up in a face photo and tag it losslessly.

Modules: ``headers`` (container parsing without decoding), ``decode`` (checked, reduced-size grey
decoding), ``geometry`` (the four rotations), ``faces`` (Haar and YuNet face finders), ``parts``
(facial parts and their arrangement), ``detect`` (detectors and the exactly-one decision),
``exif`` (the Orientation tag), ``service`` (analyze / orient_jpeg), ``job`` (the batch job),
``cli`` (``sweepcast orient``).
"""
