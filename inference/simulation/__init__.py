"""The ISAR simulator and its data sets: radar and scene (``isar``), target meshes (``targets``), sharded data
sets with one split rule (``dataset``), and the catalogues of good and bad test frames (``catalogue``).

numpy and scipy only: no torch, no onnxruntime (tests/test_layout.py holds it to that), so a bare
GPU machine can make its own training data. Physical optics (``po``) adds trimesh, embreex and numba
(``kernels``), imported only when a PO frame is made (tests/inference/simulation/test_po.py).
"""
