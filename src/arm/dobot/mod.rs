//! Dobot MG400: wire protocol (`proto`) and TCP client (`client`).
