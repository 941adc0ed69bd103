"""The synthetic world: people walking on a ground plane (``world``), their appearance
descriptors (``appearance``), a statistical people detector (``detector_model``), the scenario
schema that configures them (``schema``) and rendered video of it (``render``).
"""
