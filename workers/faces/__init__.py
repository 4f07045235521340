"""The face transformer (Arai et al.): a morphable 3D face model and impression transfer vectors.

Modules, one concept each: ``mesh`` (OBJ/PLY I/O), ``model`` (displacement PCA, eqs. 1-3, 7, 9),
``transfer`` (Fisher and SVM impression transfer vectors, eqs. 4, 5, 8), ``synthetic`` (procedural
training faces), ``dataset`` (a user's zip of registered meshes), ``train``, ``transform``,
``preview`` (a shaded software rasteriser), ``job`` (service entry points) and ``cli``.

Meshes use y up and z towards the viewer (the usual 3D-modelling axes); lengths are in the
units of the input (the synthetic faces and ICT-FaceKit are in centimetres).
"""
