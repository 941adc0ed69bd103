"""Scenarios: what the cameras see. A scenario file (``presets/``) or a det-files folder becomes a
``ScenarioData`` (``loader.load_scenario``): a seeded synthetic world (``synthetic/``), real EPFL
ground truth replayed through the synthetic detector (``epfl``), or anyone's detections in
MOTChallenge files (``detfiles``). ``replay`` lets a camera process play one camera of it.
"""
