"""phonepose: record, replay and evaluate smartphone-as-6DoF-controller AR sessions."""

__version__ = "0.1.0"
