"""The frequency domain: the finite Fourier transform (:mod:`.transform`), frequency
responses with coherence (:mod:`.response`), transfer functions and low-order equivalent
systems (:mod:`.transfer`), output error on a Model (:mod:`.output_error`) and the
covariances of these fits (:mod:`.covariance`). The public names are importable from
``estimators`` itself."""
