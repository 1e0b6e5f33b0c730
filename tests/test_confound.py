"""``kinds/multihead/_confound``: on one sensor an ``interpolation_error`` harmonic inside
the orders of the sensor's own error is reported confounded with the base's order."""

from types import SimpleNamespace

from encdesign.diagnose.kinds.multihead._confound import own_order_confound


def _prep(L: int, channels: int = 1, ref: bool = True):
    return SimpleNamespace(n_channels=channels, ctx=SimpleNamespace(signal_periods=L, has_ref=ref))


def _doc(max_order: int, located: list[int], coef: list):
    return {
        "base": {"max_order": max_order},
        "unexplained": [{"view": "orders", "where": {"orders": [float(m)]}} for m in located],
        "effects": [{"name": "interpolation_error", "params": {"coef": {"value": coef}}}],
    }


def test_a_harmonic_inside_the_sensors_own_orders_is_confounded_with_the_base():
    # L = 7: order 7 held (inside the base), order 14 fitted, orders 13 and 15 located
    d = own_order_confound(_prep(7), _doc(12, [13, 15], [0.0, 0.0, 1e-6, -2e-7]))
    (c,) = d["effects"][0]["confounded_with"]
    assert c["name"] == "base_order_14" and c["rule"] == "identifiable"


def test_a_harmonic_above_the_sensors_own_orders_is_not():
    # L = 16 over a base of orders 1-6: orders 16 and 32 are the interpolation error's alone
    d = own_order_confound(_prep(16), _doc(6, [], [[1e-6, 2e-6], [0.0, 1e-7], [0.0, 0.0], [0, 0]]))
    assert "confounded_with" not in d["effects"][0]
    # several heads: the heads' placements separate a disk order from the sensor's harmonic
    d = own_order_confound(_prep(7, channels=2), _doc(12, [13, 15], [0.0, 0.0, 1e-6, 0.0]))
    assert "confounded_with" not in d["effects"][0]
