"""The network between cameras: ``topology`` (who talks to whom) and ``inprocess`` (N camera
cores in one process exchanging encoded messages, and the centralized baseline)."""
