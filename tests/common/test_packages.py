import numpy as np

from workers.common.packages import package_version


def test_package_version_names_an_installed_distribution_and_none_for_a_missing_one():
    assert package_version("numpy") == np.__version__
    assert package_version("no-such-distribution-sweepcast") is None
