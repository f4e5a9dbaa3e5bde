"""A room thermometer and its filter: a complete Hera application in one small package."""
