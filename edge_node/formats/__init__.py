"""The file formats of the project, read and written in one place.

Camera processes (``edge_node``) and the simulator (``sim_cluster``) both use these modules, so a
file one of them writes is read by the other with the same code:

``detfile``      MOTChallenge ``det.txt`` (+ descriptors ``.npy``), ``gt.txt`` and
                 ``gt_ground.csv``: writing, and reading frame by frame on demand
``calibration``  ``calibration.json`` of a det-files directory: its cameras, frame count, units
                 and each camera's files; reading and writing
``tracks``       a node's track file ``tracks_node<id>.csv``: reading and writing
``homographies`` EPFL's ``homographies.json``: the cameras of a sequence
``layouts``      other tools' folders of detection files (MOTChallenge ``det.txt`` per camera,
                 flat or in sequence folders; homographies as JSON / NumPy; ground truth as
                 ground points or derived from the cameras' boxes), read as a calibration
``text``         every text file of the project read as UTF-8: bytes that are not are the
                 reader's own error naming the file, the line and the byte offset
"""
