"""The ports the flight flies through: vehicle, sensors, detector, recorder."""
