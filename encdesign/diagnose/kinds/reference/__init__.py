"""One sensor against a reference: the sensor candidates and their data helpers."""
