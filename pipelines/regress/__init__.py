"""The regression pipeline's parts: manifest, comparison, execution, reports.

`pipelines.regression` is the command line; these modules are the library it calls.
"""
