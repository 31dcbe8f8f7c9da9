"""A small UM-Bridge model server for the tests: ``python umbridge_server.py PORT``.

Model ``forward``: input vector ``[x, a, b]`` -> output vector ``[y, z]`` of
:func:`toy_sims.quadratic`. Serves on the loopback interface only.
"""

import functools
import sys

import umbridge
import umbridge.um


class Forward(umbridge.Model):
    def __init__(self):
        super().__init__("forward")

    def get_input_sizes(self, config):
        return [3]

    def get_output_sizes(self, config):
        return [2]

    def __call__(self, parameters, config):
        x, a, b = parameters[0]
        scale = config.get("scale", 1.0)
        return [[scale * (x * x + a * x + b), x - b]]

    def supports_evaluate(self):
        return True


if __name__ == "__main__":
    # serve_models binds every interface; keep the test server on loopback
    umbridge.um.web.run_app = functools.partial(umbridge.um.web.run_app, host="127.0.0.1",
                                                print=None)
    umbridge.serve_models([Forward()], port=int(sys.argv[1]))
