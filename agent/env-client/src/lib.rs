//! Client side of the MILLION environment API.

/// Messages and the gRPC client generated from `proto/million/env/v1/env.proto`.
pub mod proto {
    tonic::include_proto!("million.env.v1");
}
