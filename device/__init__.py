"""The virtual ESP32: direction LEDs and an emergency-stop key, the firmware's rules in Python."""
