# sumo-rl's file (github.com/LucasAlegre/sumo-rl, commit 41e4c63), run on hils with only the import changed:
# `import sumo_rl` -> `from hils import sumo_rl`. Its notice:
#
# MIT License
#
# Copyright (c) 2018 Lucas Alegre
#
# Permission is hereby granted, free of charge, to any person obtaining a copy
# of this software and associated documentation files (the "Software"), to deal
# in the Software without restriction, including without limitation the rights
# to use, copy, modify, merge, publish, distribute, sublicense, and/or sell
# copies of the Software, and to permit persons to whom the Software is
# furnished to do so, subject to the following conditions:
#
# The above copyright notice and this permission notice shall be included in all
# copies or substantial portions of the Software.
#
# THE SOFTWARE IS PROVIDED "AS IS", WITHOUT WARRANTY OF ANY KIND, EXPRESS OR
# IMPLIED, INCLUDING BUT NOT LIMITED TO THE WARRANTIES OF MERCHANTABILITY,
# FITNESS FOR A PARTICULAR PURPOSE AND NONINFRINGEMENT. IN NO EVENT SHALL THE
# AUTHORS OR COPYRIGHT HOLDERS BE LIABLE FOR ANY CLAIM, DAMAGES OR OTHER
# LIABILITY, WHETHER IN AN ACTION OF CONTRACT, TORT OR OTHERWISE, ARISING FROM,
# OUT OF OR IN CONNECTION WITH THE SOFTWARE OR THE USE OR OTHER DEALINGS IN THE
# SOFTWARE.

import gymnasium as gym
from gymnasium.utils.env_checker import check_env

from hils import sumo_rl


def test_api():
    env = gym.make(
        "sumo-rl-v0",
        num_seconds=100,
        use_gui=False,
        net_file="sumo_rl/nets/single-intersection/single-intersection.net.xml",
        route_file="sumo_rl/nets/single-intersection/single-intersection.rou.xml",
    )
    env.reset()
    check_env(env.unwrapped, skip_render_check=True)
    env.close()


if __name__ == "__main__":
    test_api()
