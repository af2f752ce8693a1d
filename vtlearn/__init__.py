"""vtlearn: visuo-tactile robot perception and learning."""

__version__ = "0.1.0"
