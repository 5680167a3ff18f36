//! CRC-64 as OpenIGTLink's header carries it over the body: ECMA-182's polynomial (0x42F0E1EBA9EA3693), most
//! significant bit first, initial value 0, no final XOR (the catalogue's CRC-64/ECMA-182, check value
//! 0x6C40DF5F0B497347 for "123456789"). A table of 256 entries built at compile time, one byte per step.

const POLY: u64 = 0x42F0_E1EB_A9EA_3693;

const TABLE: [u64; 256] = {
    let mut table = [0u64; 256];
    let mut i = 0;
    while i < 256 {
        let mut crc = (i as u64) << 56;
        let mut bit = 0;
        while bit < 8 {
            crc = if crc & (1 << 63) != 0 { (crc << 1) ^ POLY } else { crc << 1 };
            bit += 1;
        }
        table[i] = crc;
        i += 1;
    }
    table
};

/// The CRC of `bytes`, continued from `crc` (0 to start).
pub fn update(mut crc: u64, bytes: &[u8]) -> u64 {
    for &b in bytes {
        crc = TABLE[((crc >> 56) as u8 ^ b) as usize] ^ (crc << 8);
    }
    crc
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_catalogue_check_value_and_a_split_input() {
        assert_eq!(super::update(0, b"123456789"), 0x6C40_DF5F_0B49_7347);
        assert_eq!(super::update(super::update(0, b"1234"), b"56789"), 0x6C40_DF5F_0B49_7347);
        assert_eq!(super::update(0, b""), 0);
    }
}
