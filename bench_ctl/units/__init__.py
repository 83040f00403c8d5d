"""Units: unit files (TOML) and PSS/E .dyr records, the values a unit is simulated and identified with."""
