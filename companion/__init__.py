"""companion: the vehicle side of the sensor link, on a drone's companion computer (docs/real-sensor.md)."""
