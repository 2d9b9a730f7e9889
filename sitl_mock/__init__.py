"""sitl_mock"""
