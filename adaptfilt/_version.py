"""The package version, in its own module: code inside the package reads it from here, never from the
package face (``adaptfilt/__init__``), which would load the whole public API."""
__version__ = "0.1.0"
