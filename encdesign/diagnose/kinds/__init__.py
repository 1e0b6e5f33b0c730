"""The recording kinds the finder diagnoses, one folder each: how a kind reads its record,
its base model, its views and its candidate effects."""
